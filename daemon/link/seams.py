"""What the link's loop (daemon/link/loop.py) needs of its collaborators: the PTY's slave
side (:class:`Slave`, the daemon's is :class:`~motorctl.daemon.link.ports.PtySlave`) and a
listener to the bytes it reads and writes (:class:`ByteRecorder`, the daemon's is
:class:`~motorctl.daemon.link.recorder.TraceRecorder`). Tests give the loop their own.

Threads: both are called on the link thread only.
"""

from __future__ import annotations

from typing import Protocol


class Slave(Protocol):
    """The PTY's slave side, held while no host has it, its opens and closes watched
    (daemon.ports.PtySlave)."""

    @property
    def held(self) -> bool: ...

    @property
    def events_fd(self) -> int | None: ...  # readable when the slave was opened or closed

    def reopened(self) -> bool: ...  # opened again after a host closed it, since last asked

    def hold(self, answered: bool = True) -> int: ...  # held; what the last host left, flushed

    def release(self) -> None: ...

    def close(self) -> None: ...


class ByteRecorder(Protocol):
    """Told each byte run the link reads or writes, with the link clock's reading (called on
    the link thread: it must not block)."""

    def received(self, data: bytes, t: float) -> None: ...

    def sent(self, data: bytes, t: float) -> None: ...
