"""The HAL's layers: parts of the machine that work with any backend, attached to what it
built (``tmc``: TMC2130/TMC5160 driver chips over SPI).

As the backends (hal/backends/__init__.py), each is a package with its declaration
(``config.py``, a :class:`~motorctl.hal.contract.LayerDeclaration`: no hardware library) and
its implementation (``layer.py``, a :class:`~motorctl.hal.contract.Layer`); only the
registry (:mod:`motorctl.hal.registry`, ``LAYERS``) names them.
"""
