"""``[link] timeout_ms``: when the host falls silent, the motors stop (an extension, off by
default: the original microcontroller has no such rule; docs/protocol.md, "When the host
falls silent").

The rule:
- Any byte from the host keeps the link alive: whole frames, good or bad, and bytes of
  frames that never complete. (The shell tells :meth:`SilenceWatch.heard` of every read.)
- While a WaitMoved holds the link, the host is waiting for the daemon, not silent: the
  silence counts again from the moment the WaitMoved is answered (:meth:`SilenceWatch.hold`).
- ``timeout_s`` of silence: the action runs once (``act``: every motor in motion stops along
  its ramp or at once and latches a fault, E4 until StopMove; the DC motor brakes). It is
  counted, and logged when it stopped something. The next byte from the host re-arms it.
- ``timeout_s`` = 0: off; nothing is ever done.

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

    def deadline(self) -> float | None:
        """When :meth:`check` must run at the latest; None: nothing to watch."""
        if self.timeout_s <= 0 or self.fired or self.holding:
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
                "no byte from the host for %.0f ms ([link] timeout_ms = %.0f, "
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
                "no byte from the host for %.0f ms: nothing was moving", (now - self.last) * 1000
            )
        return True
