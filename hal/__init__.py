"""The HAL: what motion and the daemon know of hardware, and the backends and layers behind it.

Two parts, kept apart in the tree so that the rule is visible:

- the public face, the modules of this folder: ``interfaces.py`` (the parts every backend
  builds: clock, pins, step outputs and end-stop inputs, drivers, a driver that runs its own
  ramp, the DC bridge, the machine), ``compiled_lines.py`` (the lines a compiled step core
  may drive), ``contract.py`` (what a backend and a layer are: typed classes with their
  optional parts defaulted; what ``--probe`` reports), ``spec.py`` (what a backend is asked
  to build: plain, picklable data), ``registry.py`` (backends and layers by name: the only
  way to get one), ``shm.py`` (anonymous shared memory, which the process executor and
  the mock both use), and what the backends and layers share: ``poller.py`` (the one driver
  poller, and its ``[drivers]`` section) and ``spi.py`` (one SPI bus per device node,
  py-spidev);
- the backends, one package each under ``backends/`` (``mock``, ``gpiod``), and the layers,
  which work with any backend, under ``layers/`` (``tmc``: the TMC driver chips over SPI).
  Each has the same pattern: ``config.py`` holds its declaration (its config sections and
  what a config alone tells; no hardware library), ``backend.py`` or ``layer.py`` its
  implementation (what the registry builds; it may import its hardware library); the other
  modules are its own.

Nothing outside ``hal/`` imports from ``hal/backends/`` or ``hal/layers/``, and inside it only
the registry names them (tests/test_imports.py checks it): the daemon names a backend in its
config and the registry builds it; what only some hardware can do is asked for through
``interfaces.py`` and ``contract.py`` (``isinstance(driver, RampDriver)``, methods with
neutral defaults), never by a backend's class. So a backend can be added, or changed
inside, without touching motion or the daemon, and a reader of those rooms meets only the
interfaces. Backends and layers sit in folders of their own rather than beside the public
modules because that makes the boundary a folder, not a list of names to remember.
"""
