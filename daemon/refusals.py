"""Error answers with their reasons: the last one per motor and for the link, and the journal.

The wire carries only an error code (PROTOCOL.md §5); the reason in words is decided where
the decision is made (the dispatcher's checks in daemon/dispatcher.py, the motor's fault
latch in motion/motor.py, the link session's frame checks) and handed here with the code.
:class:`Refusals` keeps:

- the last error answered for each motor, and the last one not tied to a motor (an unknown
  motor or pin, no DC motor, a frame that failed its checks, the held-frame buffer full):
  the status document shows them (``motors[].last_error``, ``errors``; docs/status.md), and
  ``motorctl`` reads them from the status socket to print the reason beside the code;
- one journal line per error answered, rate-limited per source (each motor, and the link):
  a burst of :data:`BURST` lines, then one line every :data:`EVERY_S` seconds. What the limit
  holds back is counted, and said: in the source's next line, or in a line of its own once
  the source may log again (:meth:`Refusals.flush`, every 2 s on the status line's thread).
  A host hammering bad frames thus writes at most ``BURST`` lines and then one every
  ``EVERY_S`` seconds that says how many more there were; a motor's errors keep their own
  budget, so such a flood never hides them.

Threads: :meth:`Refusals.add` runs on the link thread (under or outside the engine lock),
:meth:`Refusals.flush` on the status line's, :meth:`Refusals.status` and
:meth:`Refusals.motor_status` on the status server's. The records are immutable and each is
put in place by one assignment; the rate limit's budgets and counts are under a lock, which
only error answers take.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from motorctl.protocol.codec import BY_NAME, Command, ErrorCode, describe

log = logging.getLogger("motorctl.errors")

#: journal lines a source may write at once, then one every EVERY_S seconds
BURST = 10
EVERY_S = 6.0
#: the link's source (errors not tied to a motor)
LINK = -1


def fix_words(name: str) -> str:
    """What the command ``name`` does when named in a fix, for the journal: "StopMove clears
    it" (the command table's remedy)."""
    cls = BY_NAME.get(name)
    return cls.spec.remedy_said if cls is not None and cls.spec.remedy else name


@dataclass(frozen=True)
class Refusal:
    """One error answer: its code, the command refused (None: a frame that failed its
    checks, then ``frame`` holds its bytes), the motor it concerns (None: not a motor of
    this machine), the reason in words and the commands that fix it, in order (protocol
    names: "StopMove", "InitMove", ...); ``at_s``: ``time.monotonic()``, ``unix_s``:
    ``time.time()`` when it was decided."""

    code: ErrorCode
    command: Command | None
    motor: int | None
    reason: str
    fix: tuple[str, ...]
    at_s: float
    unix_s: float
    frame: bytes | None = None

    def doc(self) -> dict[str, Any]:
        """The record as the status document shows it (docs/status.md)."""
        return {
            "code": self.code.short,
            "name": self.code.label,
            "command": None if self.command is None else describe(self.command),
            "frame": None if self.frame is None else self.frame.hex(" "),
            "motor": self.motor,
            "reason": self.reason,
            "fix": list(self.fix),
            "at_s": self.at_s,
            "unix_s": round(self.unix_s, 6),
        }

    def text(self) -> str:
        """The journal's words: "MoveTo(...) answered E1 Invalid Command: target 30000 is
        outside the soft limits -9000..9000"."""
        if self.command is not None:
            what = describe(self.command)
        else:
            what = "a frame" if self.frame is None else f"frame {self.frame.hex(' ')}"
        text = f"{what} answered {self.code.short} {self.code.label}: {self.reason}"
        if self.fix:
            text += "; " + ", then ".join(fix_words(name) for name in self.fix)
        return text


class _Budget:
    """One source's journal budget (a token bucket) and what it held back."""

    __slots__ = ("at", "held", "held_since", "last", "tokens")

    def __init__(self, now: float) -> None:
        self.tokens = float(BURST)
        self.at = now
        self.held = 0  # lines held back since the source's last line
        self.held_since = now
        self.last: Refusal | None = None  # the last one held back

    def take(self, now: float) -> bool:
        self.tokens = min(float(BURST), self.tokens + (now - self.at) / EVERY_S)
        self.at = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class Refusals:
    """The last error answers and their journal lines (see the module's doc). ``names``:
    the motors' names, by index; ``clock``, ``wall``: injectable for tests."""

    def __init__(
        self,
        names: Sequence[str],
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.names = list(names)
        self.clock = clock
        self.wall = wall
        self.by_motor: dict[int, Refusal] = {}
        self.link: Refusal | None = None  # the last one not tied to a motor
        self.last: Refusal | None = None
        self.answered = 0
        self.logged = 0
        self.suppressed = 0
        self._budgets: dict[int, _Budget] = {}
        self._lock = threading.Lock()

    def add(
        self,
        code: ErrorCode,
        command: Command | None,
        motor: int | None,
        reason: str,
        fix: tuple[str, ...] = (),
        frame: bytes | None = None,
    ) -> Refusal:
        """Record an error answer decided now, and write its journal line if the source's
        budget allows (else count it)."""
        now = self.clock()
        r = Refusal(code, command, motor, reason, fix, now, self.wall(), frame)
        if motor is None:
            self.link = r
        else:
            self.by_motor[motor] = r
        self.last = r
        self.answered += 1
        source = LINK if motor is None else motor
        with self._lock:
            budget = self._budgets.get(source)
            if budget is None:
                budget = self._budgets[source] = _Budget(now)
            if not budget.take(now):
                budget.held += 1
                budget.last = r
                self.suppressed += 1
                return r
            held, since = budget.held, budget.held_since
            budget.held, budget.held_since, budget.last = 0, now, None
            self.logged += 1
        line = r.text()
        if held:
            line += f" (and {held} more not logged in the last {now - since:.1f} s)"
        self._log(source, r, line, held)
        return r

    def flush(self) -> None:
        """Say what the limit held back, for each source that may log again (called every
        couple of seconds, off the link thread)."""
        now = self.clock()
        due: list[tuple[int, int, float, Refusal]] = []
        with self._lock:
            for source, budget in self._budgets.items():
                if budget.held and budget.last is not None and budget.take(now):
                    due.append((source, budget.held, now - budget.held_since, budget.last))
                    budget.held, budget.held_since, budget.last = 0, now, None
                    self.logged += 1
        for source, held, seconds, last in due:
            line = (
                f"{held} more error answers not logged in the last {seconds:.1f} s; "
                f"the last: {last.text()}"
            )
            self._log(source, last, line, held)

    def _log(self, source: int, r: Refusal, line: str, held: int) -> None:
        who = "link" if source == LINK else self._motor_name(source)
        level = logging.INFO if r.code is ErrorCode.MOTOR_NOT_READY else logging.WARNING
        fields: dict[str, object] = {"ERROR_CODE": r.code.short}
        if r.command is not None:
            fields["COMMAND"] = r.command.spec.name
        if r.motor is not None:
            fields["MOTOR"] = r.motor
        if held:
            fields["SUPPRESSED"] = held
        log.log(level, "%s: %s", who, line, extra=fields)

    def _motor_name(self, index: int) -> str:
        name = self.names[index] if 0 <= index < len(self.names) else None
        return f"motor {index}" if name is None else f"motor {index} ({name})"

    # -- the status document ------------------------------------------------------------
    def motor_status(self, index: int) -> dict[str, Any] | None:
        """``motors[index].last_error``: the last error answered for that motor, or None."""
        r = self.by_motor.get(index)
        return None if r is None else r.doc()

    def status(self) -> dict[str, Any]:
        """The document's ``errors``: counts, the journal's limit, the last error answered
        and the last one not tied to a motor."""
        last, link = self.last, self.link
        return {
            "answered": self.answered,
            "logged": self.logged,
            "suppressed": self.suppressed,
            "journal_burst": BURST,
            "journal_every_s": EVERY_S,
            "last": None if last is None else last.doc(),
            "link": None if link is None else link.doc(),
        }
