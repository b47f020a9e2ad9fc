"""``[link] timeout_ms``: when the host falls silent, the motors stop (an extension, off by
default: the original microcontroller has no such rule; docs/protocol.md, "When the host
falls silent").

The rule:
- Any byte from the host keeps the link alive: whole frames, good or bad, and bytes of
  frames that never complete. (The shell tells :meth:`SilenceWatch.heard` of every read.)
- While a WaitMoved holds the link, the host is waiting for the daemon, not silent: the
  silence counts again from the moment the WaitMoved is answered (:meth:`SilenceWatch.hold`).
- Silence is time in which no byte arrived *while the daemon was ready to read* (the frame
  gap's rule): while the daemon holds back (back pressure: the host does not read its
  answers, so the daemon does not read its frames; the host's bytes wait in the kernel) the
  silence does not count (:meth:`SilenceWatch.listening`), and the shell checks the silence
  only after a read has found nothing waiting.
- ``timeout_s`` of silence: the action runs once (``act``: every motor in motion stops along
  its ramp or at once and latches a fault, E4 until StopMove; the DC motor brakes). It is
  counted, and logged when it stopped something. The next byte from the host re-arms it.
- ``timeout_s`` = 0: off; nothing is ever done. Above 0 it must be at least one frame's
  time on the line (:func:`min_timeout_ms`): less could not be kept by any host.

Pure: the times come from the caller (the link thread's clock, a virtual one in tests); the
action is a callback. Owned by the link thread; :attr:`counters` may be copied by the status
thread (every key exists from the start).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence

log = logging.getLogger("motorctl.link")

COUNTERS = ("link_timeouts", "link_timeout_stops")

#: one command frame on the line: 10 bytes of 10 bits each (start, 8 data, stop; 8N1)
FRAME_BITS = 100


def min_timeout_ms(baud: int) -> float:
    """The shortest ``[link] timeout_ms`` above 0: one frame's time at ``baud``."""
    return FRAME_BITS * 1000.0 / baud


def check_timeout(timeout_ms: float, baud: int) -> str | None:
    """Why ``timeout_ms`` cannot be kept at ``baud`` (None: it can, or it is off)."""
    least = min_timeout_ms(baud)
    if 0 < timeout_ms < least:
        return (
            f"[link] timeout_ms = {timeout_ms:g} is shorter than one frame at {baud} baud "
            f"({least:.3g} ms for 10 bytes of 10 bits): no host can keep it. Use 0 (off) "
            f"or at least {least:.3g} ms; a useful value is many frames long (the host "
            "must send a byte at least this often while its motors move)"
        )
    return None


#: what the action gets (the time) and returns (what it stopped, for the log: "motor 0 (x)")
Action = Callable[[float], Sequence[str]]


class SilenceWatch:
    def __init__(
        self,
        timeout_s: float,
        act: Action | None = None,
        now: float = 0.0,
        action: str = "decelerate",
    ) -> None:
        if timeout_s < 0:
            raise ValueError("timeout_s must be >= 0")
        if timeout_s > 0 and act is None:
            raise ValueError("a timeout needs an action")
        self.timeout_s = timeout_s
        self.act = act
        self.action = action  # its name, for the log
        self.last = now  # the latest sign of life
        self.fired = False  # the action ran for this silence (until the next byte)
        self.holding = False  # a WaitMoved holds the link
        self.deaf_since: float | None = None  # the daemon does not read (back pressure)
        self.counters: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))

    @property
    def enabled(self) -> bool:
        return self.timeout_s > 0

    def heard(self, now: float) -> None:
        """Bytes came from the host at ``now``."""
        self.last = now
        self.fired = False

    def hold(self, waiting: bool, now: float) -> None:
        """Whether a WaitMoved holds the link at ``now``; its end restarts the silence."""
        if waiting:
            self.holding = True
        elif self.holding:
            self.holding = False
            self.last = now
            self.fired = False

    def listening(self, reading: bool, now: float) -> None:
        """Whether the daemon reads at ``now``. While it does not (back pressure), no byte
        can arrive for it: that time is not silence (the silence before it still counts)."""
        if not reading:
            if self.deaf_since is None:
                self.deaf_since = now
        elif self.deaf_since is not None:
            self.last += now - self.deaf_since
            self.deaf_since = None

    def deadline(self) -> float | None:
        """When :meth:`check` must run at the latest; None: nothing to watch."""
        if self.timeout_s <= 0 or self.fired or self.holding or self.deaf_since is not None:
            return None
        return self.last + self.timeout_s

    def check(self, now: float) -> bool:
        """Run the action if the host has been silent for ``timeout_s``; True if it ran."""
        due = self.deadline()
        if due is None or now < due:
            return False
        self.fired = True
        assert self.act is not None
        stopped = list(self.act(now))
        if stopped:
            self.counters["link_timeouts"] += 1
            self.counters["link_timeout_stops"] += len(stopped)
            log.warning(
                "no byte from the host for %.1f ms ([link] timeout_ms = %g, "
                "action %s): stopped %s; a stopped motor answers E4 until a StopMove "
                "clears it",
                (now - self.last) * 1000,
                self.timeout_s * 1000,
                self.action,
                ", ".join(stopped),
                extra={"EVENT": "link_timeout"},
            )
        else:
            log.debug(
                "no byte from the host for %.1f ms ([link] timeout_ms = %g): nothing was moving",
                (now - self.last) * 1000,
                self.timeout_s * 1000,
            )
        return True
