"""The end of a host's session, as the link's loop records it: what was owed to the host
and dropped, counted by cause, and said in the log a moment later; and what the host wrote
that the daemon had not read, read out of the PTY (:func:`read_out`).

A host's session ends when it closes the port or its serial device goes away
(daemon/link/loop.py decides when; daemon/link/session.py drops what was owed). Every
answer dropped is counted in the link's counters, in ``responses_dropped`` and in
``responses_dropped_<cause>``: ``unsent`` (answers written or due that the host never
read), ``wait`` (a held WaitMoved's answer), ``held`` (the answers of the frames kept behind
it) and ``shutdown`` (answers still unsent when the daemon stopped). The frames the host
wrote and the daemon had not read yet (back pressure: the daemon stops reading while 4096
answers are owed, and the rest waits in the kernel, up to its buffers) are the session's
too: read out at its end and dropped, never executed for the next host
(``unread_frames_dropped``), but a StopMove among them, carried out
(``unread_stops_executed``). A session that left something is logged at INFO, not at once
but once the line has been quiet for ``SAY_AFTER_S`` (the log costs more than a command: a
new host's first command, maybe on its way, is answered first); one that left nothing at
DEBUG. Sessions that ended less than ``SAY_AFTER_S`` apart (a host that reconnects over and
over) are said in one line, their count and what they left in all: the link thread's cost
of the saying is one line however many ended (one line each made it wait 35-87 ms for
600-1,200 of them, inside a new host's first round trip: docs/timing.md), and what waits to
be said is a few numbers, not a list that grows with every reconnect. A line that is never
quiet (a host reconnecting more often than every ``SAY_AFTER_S``, for minutes) still gets its
ends said, at the latest ``SAY_WITHIN_S`` after the first of them: one line a second at most.

Threads: the link thread's, like the loop that owns it; it blocks on nothing (the PTY's
master is non-blocking).
"""

from __future__ import annotations

import errno
import logging
import os
from collections import Counter
from collections.abc import Callable

from motorctl.daemon.link.session import Ended

log = logging.getLogger("motorctl.link")

SAY_AFTER_S = 0.02  # a session's end is logged this long after it
SAY_WITHIN_S = 1.0  # ... or this long after the first end not said yet, quiet line or not

#: why an answer owed to a host was dropped: responses_dropped_<cause>
CAUSES = ("unsent", "wait", "held", "shutdown")
#: the link's counters of ended sessions (all of them exist from the start)
END_COUNTERS = (
    "hangup_partial_bytes",
    "unread_frames_dropped",
    "unread_stops_executed",
    "responses_dropped",
    *(f"responses_dropped_{cause}" for cause in CAUSES),
)
#: bytes read out at most at a session's end: more than a PTY's kernel buffers hold (its line
#: discipline's 4 KiB and its flip buffers' 64 KiB); one read takes up to UNREAD_READ
UNREAD_MAX = 1 << 20
UNREAD_READ = 1 << 16


def read_out(master: int, reopened: Callable[[], bool]) -> tuple[bytes, bytes, bool]:
    """What the host that closed the PTY wrote and the daemon had not read: the kernel keeps
    it for the master, read out here until none is left. A read that finds nothing first
    waits for what the kernel is still moving into the master's input; it then fails with
    EIO when nobody has the slave open (all of it was the old host's), or with EAGAIN when
    somebody opened it since (a new host).

    ``reopened()`` (the slave's watch: a new host opened the port since the close) is asked
    before the first read and after each: a host's open is reported before anything it
    writes can be read, so a read after which no open is reported holds the old host's
    bytes only; the read after which one is, may hold the new host's first bytes too (they
    cannot be told apart, docs/protocol.md): it is the new session's. Returns the old
    host's bytes, the new session's, and whether a new host has the port; at most
    :data:`UNREAD_MAX` bytes (a new host writing all the while, unseen)."""
    out = bytearray()
    if reopened():
        return b"", b"", True
    while len(out) < UNREAD_MAX:
        try:
            chunk = os.read(master, UNREAD_READ)
        except InterruptedError:
            continue
        except BlockingIOError:
            return bytes(out), b"", True
        except OSError as exc:  # EIO: nothing left, and nobody has the slave
            if exc.errno != errno.EIO:
                log.warning("cannot read what the last host left unread: %s", exc)
            return bytes(out), b"", False
        if not chunk:
            break
        if reopened():
            return bytes(out), chunk, True
        out += chunk
    return bytes(out), b"", False


class SessionEnds:
    """Counts what ended sessions left in ``counters`` (the link's) and says it in the log
    a moment later (on the link thread's ``clock``)."""

    def __init__(self, counters: Counter[str], clock: Callable[[], float]) -> None:
        self.counters = counters
        self.clock = clock
        # the session ends not said yet: how each ended, and what they left, in all
        self._hows: Counter[str] = Counter()
        self._left = NOTHING
        self._unsent = 0
        self._first_at = 0.0  # the first of them
        self._later_at = 0.0  # the last of them

    def drop(self, cause: str, answers: int) -> None:
        """``answers`` owed to a host dropped, for ``cause`` (one of :data:`CAUSES`)."""
        if answers:
            self.counters["responses_dropped"] += answers
            self.counters[f"responses_dropped_{cause}"] += answers

    def ended(self, how: str, ended: Ended, unsent: int) -> None:
        """A session ended (``how``, for the log): what the session dropped (``ended``) and
        ``unsent`` answers that were written or due, counted; said a moment later."""
        self.counters["hangup_partial_bytes"] += ended.partial_bytes
        self.counters["unread_frames_dropped"] += ended.unread_frames
        self.counters["unread_stops_executed"] += ended.unread_stops
        self.drop("unsent", unsent)
        self.drop("wait", ended.wait)
        self.drop("held", ended.held)
        if unsent or ended.wait or ended.held or ended.partial_bytes or ended.unread_frames:
            # said a moment later (the log costs more than a command): a new host's first
            # command, maybe on its way, is answered first
            self._later_at = self.clock()
            if not self._hows:
                self._first_at = self._later_at
            self._hows[how] += 1
            self._left = added(self._left, ended)
            self._unsent += unsent
        else:
            log.debug("%s; serving the next host", how)

    def bound(self, now: float, timeout_ms: float | None) -> float | None:
        """Say what is due by ``now``; ``timeout_ms`` (a poll's, None: none) shortened to
        when the next saying is due. Said once the line has been quiet a moment, not before
        a new host's first command; at the latest ``SAY_WITHIN_S`` after the first end not
        said yet."""
        if not self._hows:
            return timeout_ms
        due = min(self._later_at + SAY_AFTER_S, self._first_at + SAY_WITHIN_S)
        left = (due - now) * 1000.0
        if left <= 0:
            self.say()
        elif timeout_ms is None or left < timeout_ms:
            return left
        return timeout_ms

    def say(self) -> None:
        """Log the session ends not said yet: one line, however many they are."""
        sessions = self._hows.total()
        if sessions == 1:
            log.info(
                "%s: dropped what its host did not read (%s); serving the next host",
                next(iter(self._hows)),
                describe_ended(self._left, self._unsent),
                extra={"EVENT": "session_ended"},
            )
        elif sessions:
            log.info(
                "%d sessions ended less than %.0f ms apart (%s): dropped what their hosts "
                "did not read (in all: %s); serving the next host",
                sessions,
                SAY_AFTER_S * 1000,
                ", ".join(f"{how}: {n}" for how, n in self._hows.items()),
                describe_ended(self._left, self._unsent),
                extra={"EVENT": "session_ended", "SESSIONS": sessions},
            )
        self._hows.clear()
        self._left = NOTHING
        self._unsent = 0


#: what a session that left nothing left
NOTHING = Ended(0, 0, 0, 0, 0)


def added(a: Ended, b: Ended) -> Ended:
    """What two ended sessions left, in all."""
    return Ended(
        a.partial_bytes + b.partial_bytes,
        a.unsent + b.unsent,
        a.wait + b.wait,
        a.held + b.held,
        a.discarded + b.discarded,
        a.unread_frames + b.unread_frames,
        a.unread_stops + b.unread_stops,
    )


def describe_ended(ended: Ended, unsent: int) -> str:
    """What an ended session left, in words, for the log."""
    parts = []
    if unsent:
        parts.append(f"{unsent} answers written or due")
    if ended.wait == 1:
        parts.append("a held WaitMoved's answer")
    elif ended.wait:
        parts.append(f"{ended.wait} held WaitMoveds' answers")
    if ended.held:
        kept = f"{ended.held} frames kept behind {'it' if ended.wait <= 1 else 'them'}"
        if ended.discarded:
            kept += f" ({ended.discarded} commands not executed)"
        parts.append(kept)
    if ended.unread_frames:
        unread = f"{ended.unread_frames} frames it wrote that were not read yet"
        if ended.unread_stops:
            unread += f" ({ended.unread_stops} StopMoves among them carried out)"
        parts.append(unread)
    if ended.partial_bytes:
        parts.append(f"{ended.partial_bytes} bytes of an incomplete frame")
    return ", ".join(parts)
