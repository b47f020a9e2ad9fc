"""The ``process`` step executor: the step core in a process of its own.

- ``start.py``: starts the process's interpreter early (light to import: nothing of
  motorctl);
- ``rings.py``: the block of shared memory between the two processes, its layout, rings and
  records, the one contract both sides read;
- ``child.py``: the executor process (real time, its own lines, a step core over the block);
- ``parent.py``: the daemon's side (``ProcessStepExecutor``).

Nothing is imported here (see ``start.py``).
"""
