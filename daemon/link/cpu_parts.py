"""The link thread's CPU time, part by part: what bench/latency.py prints per round trip.

Off unless asked for (``MOTORCTL_LINK_CPU_PARTS=1`` in motorctld's environment,
:func:`motorctl.daemon.start.link_parts.cpu_parts`): the link then gets a :class:`CpuParts` and
its session a :class:`TimedPort` in front of the dispatcher; without one, the link's only
cost is a test for None at the four places it would mark.

Each mark reads the thread's CPU clock (``time.thread_time_ns``) and gives the time since
the last mark to the part that just ended, so every nanosecond of the thread's CPU goes to
exactly one part (the marks' own cost too: about 0.1-0.3 us each, a system call):

- ``poll``: the ``poll()`` system call (the kernel's work on entry and on waking);
- ``read``: the port's ``read()``, and the PTY watch's look for a reopened port;
- ``decode``: from the read to the command (the session's counters, the framer or the
  one-frame path, the decoded-frame cache, the silence watch's note, the trace);
- ``dispatch``: the dispatcher's work for the command (the engine lock, the motor);
- ``encode``: from the answer to the bytes about to be written (the encoded-answer cache,
  the counters, the last frames kept for the status, the output taken);
- ``write``: the port's ``write()``;
- ``bookkeeping``: the rest of a turn: the processing time's record, the session's start
  and end, the next turn's set-up up to ``poll()``.

Threads: the link thread marks; the status thread copies the totals (:meth:`summary`: one
C-level dict copy under the GIL).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from motorctl.daemon.dispatcher import Wait
from motorctl.daemon.link.session import CommandPort
from motorctl.protocol.codec import Command, ErrorCode, Response, WaitMoved

#: the parts, in the order a round trip goes through them
PARTS = ("poll", "read", "decode", "dispatch", "encode", "write", "bookkeeping")


class CpuParts:
    """CPU nanoseconds of one thread per part (:data:`PARTS`), on ``clock``."""

    def __init__(self, clock: Callable[[], int] = time.thread_time_ns) -> None:
        self._clock = clock
        self.ns = dict.fromkeys(PARTS, 0)
        self.commands = 0  # commands dispatched
        self._last = clock()

    def mark(self, part: str) -> None:
        """``part`` ended now: the time since the last mark was spent on it."""
        now = self._clock()
        self.ns[part] += now - self._last
        self._last = now

    def summary(self) -> dict[str, object]:
        """The totals so far (any thread): ``ns`` per part, ``commands`` dispatched."""
        return {"ns": self.ns.copy(), "commands": self.commands}


class TimedPort:
    """The dispatcher as the session sees it, each command's dispatch marked: the time
    before it (since the read) is ``decode``, its own is ``dispatch``."""

    def __init__(self, port: CommandPort, parts: CpuParts) -> None:
        self.port = port
        self.parts = parts

    def handle(self, cmd: Command) -> Response:
        parts = self.parts
        parts.mark("decode")
        try:
            return self.port.handle(cmd)
        finally:
            parts.commands += 1
            parts.mark("dispatch")

    def wait_begin(self, cmd: WaitMoved, now: float) -> Response | Wait:
        parts = self.parts
        parts.mark("decode")
        try:
            return self.port.wait_begin(cmd, now)
        finally:
            parts.commands += 1
            parts.mark("dispatch")

    def wait_poll(self, wait: Wait, now: float) -> Response | None:
        return self.port.wait_poll(wait, now)

    def refused(
        self,
        code: ErrorCode,
        reason: str,
        command: Command | None = None,
        frame: bytes | None = None,
    ) -> None:
        self.port.refused(code, reason, command, frame)
