"""The motion engine: all motors and the DC motor on one clock.

``service(now)`` does everything that is due (step edges, the end of a DC run,
driver polls) and ``next_deadline()`` says when the next thing is due. The real
step thread (:mod:`motion.stepthread`) calls them against the monotonic clock;
tests call :meth:`run_until` against a virtual clock.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

from motorctl.hal.interfaces import BridgeState, Hardware, VirtualClock
from motorctl.motion.dc import DcMotor
from motorctl.motion.latency import LatencyStats
from motorctl.motion.motor import Motor
from motorctl.motion.types import MotorParams

log = logging.getLogger("motorctl.motion")

Listener = Callable[[Motor, str], None]


class MotionEngine:
    def __init__(
        self,
        hw: Hardware,
        params: Sequence[MotorParams],
        *,
        endstop_active_low: Sequence[bool] | None = None,
        driver_poll_s: float = 0.01,
        late_threshold_s: float = 100e-6,
    ) -> None:
        if len(params) != len(hw.steppers):
            raise ValueError(f"{len(params)} motors configured, hardware has {len(hw.steppers)}")
        self.hw = hw
        self.clock = hw.clock
        self.lock = threading.RLock()
        self.wake = threading.Event()
        self.stats = LatencyStats(late_threshold_s)
        self.listeners: list[Listener] = []
        lows = list(endstop_active_low or [False] * len(params))
        self.motors = [
            Motor(i, p, hw.steppers[i], self.stats, self._notify, lows[i])
            for i, p in enumerate(params)
        ]
        self.dc = DcMotor(hw.dc) if hw.dc is not None else None
        self.driver_poll_s = driver_poll_s
        self.hardware_errors = 0  # backend calls that raised in service()
        self._next_poll = self.clock.now() + driver_poll_s

    # -- notifications -------------------------------------------------------
    def _notify(self, motor: Motor, event: str) -> None:
        for listener in self.listeners:
            listener(motor, event)
        self.wake.set()

    @property
    def any_active(self) -> bool:
        return any(m.active for m in self.motors) or (self.dc is not None and self.dc.running)

    # -- commands (callers hold self.lock) -------------------------------------
    def dc_run(self, forward: bool, duration_s: float, end: BridgeState) -> None:
        if self.dc is None:
            raise LookupError("no DC motor")
        self.dc.run(forward, duration_s, end, self.clock.now())
        self.wake.set()

    # -- the clock's side --------------------------------------------------------
    def next_step_deadline(self) -> float | None:
        """The next step edge: the only deadline worth spinning for."""
        best: float | None = None
        for m in self.motors:
            step = m.next_step
            if step is not None and (best is None or step[0] < best):
                best = step[0]
        return best

    def next_coarse_deadline(self) -> float:
        """The next driver poll or end of a DC run: millisecond matters, no spinning."""
        best = self._next_poll
        if self.dc is not None and self.dc.deadline is not None and self.dc.deadline < best:
            best = self.dc.deadline
        return best

    def next_deadline(self) -> float:
        step = self.next_step_deadline()
        coarse = self.next_coarse_deadline()
        return coarse if step is None or coarse < step else step

    def service(self, now: float) -> None:
        """Do everything due at or before ``now``.

        A line or device that fails (the backend raises) latches a fault on its motor; the
        caller, usually the step thread, carries on."""
        for m in self.motors:
            try:
                while m.next_step is not None and m.next_step[0] <= now:
                    m.fire(now)
            except Exception as exc:
                self._hardware_fault(m, exc, now)
        if self.dc is not None:
            try:
                self.dc.service(now)
            except Exception as exc:
                self.hardware_errors += 1
                log.error("DC motor: the bridge failed: %s", exc)
        if now >= self._next_poll:
            self._next_poll = now + self.driver_poll_s
            for m in self.motors:
                try:
                    m.poll_driver(now)
                except Exception as exc:
                    self._hardware_fault(m, exc, now)

    def _hardware_fault(self, m: Motor, exc: Exception, now: float) -> None:
        self.hardware_errors += 1
        log.error("motor %d (%s): hardware error: %s", m.index, m.params.name, exc)
        m.latch_fault(f"hardware error: {exc}", now)

    def run_until(self, t: float) -> None:
        """Drive a virtual clock to ``t``, doing everything due on the way, in time order."""
        clock = self.clock
        if not isinstance(clock, VirtualClock):
            raise TypeError("run_until needs a VirtualClock")
        with self.lock:
            while True:
                d = self.next_deadline()
                if d > t:
                    break
                clock.advance_to(d)
                self.service(clock.now())
            clock.advance_to(t)

    def run_until_idle(self, limit_s: float = 600.0) -> None:
        """Virtual clock: run until no motor moves and no DC run is on (or ``limit_s``)."""
        clock = self.clock
        if not isinstance(clock, VirtualClock):
            raise TypeError("run_until_idle needs a VirtualClock")
        end = clock.now() + limit_s
        with self.lock:
            while self.any_active or any(m.queue for m in self.motors):
                d = self.next_deadline()
                if d > end:
                    raise TimeoutError("motion did not finish")
                clock.advance_to(d)
                self.service(clock.now())

    def shutdown(self) -> None:
        """Soft-stop every motor (callers then wait until idle), brake the DC motor."""
        with self.lock:
            now = self.clock.now()
            for m in self.motors:
                m.stop(hard=False, now=now)
            if self.dc is not None:
                self.dc.stop(BridgeState.BRAKE)
            self.wake.set()
