"""The state wing: what the daemon keeps on disk, and how it writes any file.

- records.py: the state files' format and strict reading (what a saved motor is, what is
  trusted, how saved motors are matched with the configured ones);
- files.py: the rule of every path the daemon creates or writes (never a link followed, a
  FIFO or a device opened, someone else's file written; whatever else stands there set
  aside), and complete-or-absent writes; the lock, the status socket and the trace use it too;
- journal.py: the motion journal, "moving" made durable before a motion's ACK;
- writer.py: the state writer's thread;
- persistence.py: restore at start, snapshots, the dispatcher's hooks.

The lowest wing: it imports nothing of the daemon outside itself (tests/test_imports.py).
Each module says which thread owns what.
"""
