"""The HAL's backends, one package each: what builds a machine, or a part of it, by name.

Nothing outside ``hal/`` imports from here: the daemon and motion ask for a backend by its
name through :mod:`motorctl.hal.registry` and use what it builds through the interfaces of
:mod:`motorctl.hal.interfaces` (hal/__init__.py says why). Each package holds:

- ``config.py``: its config sections (imported whenever a config is read: no hardware
  library here);
- ``backend.py``: the entry points the registry names (imported only when the config
  chooses it: it may import its hardware library);
- the modules those two use, private to the package.
"""
