"""The HAL's backends, one package each: what builds a machine by name (``[hal] backend``).

Nothing outside ``hal/`` imports from here, and inside it only the registry names them: the
daemon and motion ask for a backend by its name through :mod:`motorctl.hal.registry` and use
what it builds through the interfaces of :mod:`motorctl.hal.interfaces` (hal/__init__.py
says why). Each package holds:

- ``config.py``: its declaration (:class:`~motorctl.hal.contract.BackendDeclaration`): its
  config sections, imported whenever a config is read (no hardware library here);
- ``backend.py``: its :class:`~motorctl.hal.contract.Backend`, imported only when the config
  chooses it (it may import its hardware library);
- the modules those two use, private to the package.
"""
