"""motorctl: a Linux daemon that stands in for a motor-controller microcontroller on a UART.

This folder holds the namespace root, ``schema/`` (the generic config-schema engine that
every room may use: it imports nothing from motorctl) and, in a checkout, relative symlinks
to the rooms. The rooms are the repository's top-level folders, mapped under this name by
``[tool.setuptools.package-dir]`` in pyproject.toml:

    client/   -> motorctl.client    host side: library and the ``motorctl`` CLI
    protocol/ -> motorctl.protocol  pure, shared by both sides: codec, CRC, framing, positions
    daemon/   -> motorctl.daemon    device side: link, dispatcher, config, state, service
    motion/   -> motorctl.motion    steps, step/s, step/s^2: profiles, motors, executors
    hal/      -> motorctl.hal       the edge: interfaces and backends by name

Dependencies point one way: client -> protocol <- daemon -> motion -> hal.
"""

__version__ = "0.2.0"
