"""The mock backend: a simulated machine (``world.py``: axes with end stops, wired pins, a DC
bridge) whose every edge goes to a timeline; the daemon's embedded default. Its declaration
in ``config.py``, the Backend in ``backend.py``."""
