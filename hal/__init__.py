"""The HAL: what motion and the daemon know of hardware, and the backends behind it.

Two parts, kept apart in the tree so that the rule is visible:

- the public face, the modules of this folder: ``interfaces.py`` (the interfaces and
  capabilities every backend implements: clock, pins, step outputs and end-stop inputs,
  drivers, a driver that runs its own ramp, the DC bridge, the machine), ``spec.py`` (what
  a backend is asked to build: plain, picklable data), ``registry.py`` (backends and
  layers by name: the only way to get one) and ``shm.py`` (anonymous shared memory, which
  the process executor and the mock both use);
- the backends, one package each under ``backends/`` (``mock``, ``gpiod``, and ``tmc``, the
  SPI driver layer), each with the same pattern: ``config.py`` declares its config sections
  and imports no hardware library; ``backend.py`` holds what the registry calls and may
  import its hardware library; the other modules are its own.

Nothing outside ``hal/`` imports from ``hal/backends/`` (tests/test_imports.py checks it):
the daemon names a backend in its config and the registry builds it; what only some
hardware can do is asked for through ``interfaces.py`` (``isinstance(driver,
RampDriver)``, methods with neutral defaults), never by a backend's class. So a backend can
be added, or changed inside, without touching motion or the daemon, and a reader of those
rooms meets only the interfaces. Backends sit together rather than beside the public
modules because that makes the boundary a folder, not a list of names to remember.
"""
