"""The driver monitor: one thread that polls every TMC driver's DRV_STATUS at its rate.

Threads: :class:`DriverMonitor` runs the ``tmc-monitor`` thread; it owns only its schedule
and calls each driver's ``poll`` (which belongs to this thread, see ``driver.py``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from motorctl.hal.layers.tmc.driver import TmcDriver

log = logging.getLogger("motorctl.tmc")


@dataclass
class _Entry:
    driver: TmcDriver
    period_s: float
    due: float = 0.0


@dataclass
class DriverMonitor:
    """One thread that polls every driver's DRV_STATUS at that driver's rate.

    It owns only its schedule; each driver's poll catches its own SPI errors and turns them
    into a latched fault, and an unexpected exception in one poll is logged and latched as
    a fault of that driver: the thread never dies. ``stop()`` returns within ``join_s``.
    """

    drivers: Sequence[TmcDriver]
    now: Callable[[], float]
    join_s: float = 2.0
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    rounds: int = 0

    def start(self) -> None:
        if self._thread is not None or not self.drivers:
            return
        self._thread = threading.Thread(target=self._run, name="tmc-monitor", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(self.join_s)
            if thread.is_alive():
                log.error("the driver monitor did not stop within %.1f s", self.join_s)

    def poll_due(self, entries: list[_Entry]) -> float:
        """Poll what is due; returns the time until the next poll is due."""
        now = self.now()
        for e in entries:
            if now >= e.due:
                e.due = now + e.period_s
                try:
                    e.driver.poll()
                except Exception as exc:  # a bug must not kill the monitor: latch and go on
                    log.exception("%s: driver poll failed", e.driver.name)
                    e.driver._set_transient(f"internal error in the driver monitor: {exc!r}")
                    e.driver._publish(None)
        self.rounds += 1
        return max(0.0, min(e.due for e in entries) - self.now())

    def _run(self) -> None:
        entries = [_Entry(d, d.settings.poll_ms / 1000.0) for d in self.drivers]
        while not self._stop.is_set():
            wait = self.poll_due(entries)
            self._stop.wait(wait)
