"""The gpiod backend: STEP/DIR, end stops, an H-bridge and IO pins on Linux GPIO lines through
libgpiod (its v1 or v2 Python API: ``chip.py``, each binding in ``binding_v1.py`` and
``binding_v2.py``), wired as ``wiring.py`` says: its declaration in ``config.py``, the Backend
in ``backend.py``, its parts in ``parts.py`` and ``bridge.py``, ``--probe`` in ``probe.py``,
the Raspberry Pi board layouts it names in ``boards.py``."""
