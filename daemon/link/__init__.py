"""The link wing: the serial line between the host and the dispatcher.

- loop.py: the poll/read/write loop (``Link``), a thin shell around
- session.py: the pure protocol side of the link (framing by watched silence, ordering,
  held frames, WaitMoved): bytes and times in, answers out; no descriptor, no clock;
- session_end.py: what a host's ended session left, counted by cause and logged;
- silence.py: ``[link] timeout_ms``, the host's silence (pure, like the session);
- ports.py: the PTY (``--pty``) and its slave side held while no host has it;
- serialport.py: the UART (``--port``), opened and opened again by its path;
- devwatch.py: a serial device's return noticed (inotify) and tried (backoff);
- recorder.py: the link's trace file (``--trace``).

It reads the state wing's safe files (daemon/state/files.py) and the dispatcher's types,
never the status wing, the assembler or the serve module (tests/test_imports.py). Each
module says which thread owns what.
"""
