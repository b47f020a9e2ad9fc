"""The executors: what carries out the motion the motor state machines plan.

One job a module; ``base.py`` is the wing's one door (tests/test_imports.py keeps it so):

- ``base.py``: the :class:`~motorctl.motion.executors.base.Executor` contract, its events
  and records, the step path's integer time. The motor state machines and the engine import
  this module and nothing else of the wing; the assembler (``daemon/start/assemble.py``) chooses
  and builds the rest.
- ``planner.py``: the step executors' planner half (cuts plans into ``segments.py``'s step
  segments a few ms ahead); each kind implements its transport to a step core.
- ``step_core.py``: the hot loop, the Python reference; ``compiled_core.py`` and ``csrc/``:
  its compiled twin (the C extension ``_stepcore``).
- ``thread.py``: the core in a thread of the daemon (or on a virtual clock).
- ``process/``: the core in a process of its own (``process/rings.py``,
  ``process/child.py``, ``process/parent.py``, ``process/start.py``).
- ``chip_ramp.py``: driver chips that run their own ramp; ``split.py``: each motor to the
  executor that moves it.

Nothing is imported here: ``process/start.py`` must stay light to import (the daemon's
launch imports it before anything else).
"""
