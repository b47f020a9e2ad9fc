"""The motion engine: every motor's state machine, the DC motor and one executor.

Owner: ``engine.lock`` (the motion lock), taken by the dispatcher, the planner thread and
the driver monitor for short, bounded work (state machines, planning a few ms of steps).
The step path never takes it: it is the executor's, fed through queues.

Threads on a real clock (:meth:`start`): the planner thread (events from the executor,
refilling step segments, DC run ends; normal priority) and the driver monitor (reads
every driver's status outside the lock, then latches faults under it). Tests on a virtual
clock call :meth:`run_until` instead: executor steps, planner, DC and polls in time order.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

from motorctl.hal.interfaces import (
    BridgeState,
    DriverStatus,
    HalError,
    Hardware,
    VirtualClock,
)
from motorctl.motion.dc import DcMotor
from motorctl.motion.executor import ExecEvent, ExecEventKind, Executor, from_ticks, to_ticks
from motorctl.motion.motor import Motor
from motorctl.motion.types import MotorParams

log = logging.getLogger("motorctl.engine")

def _on_tick(t: float) -> float:
    """A virtual clock only stops on the step path's ticks, so edges land on their times."""
    return from_ticks(to_ticks(t))


Listener = Callable[[Motor, str], None]
#: the planner thread wakes at least this often (its progress is part of health)
PLANNER_TICK_S = 0.005


class MotionEngine:
    def __init__(
        self,
        hw: Hardware,
        params: Sequence[MotorParams],
        executor: Executor,
        *,
        driver_poll_s: float = 0.01,
    ) -> None:
        if len(params) != len(hw.steppers):
            raise ValueError(f"{len(params)} motors configured, hardware has {len(hw.steppers)}")
        if executor.motors != len(params):
            raise ValueError(f"the executor drives {executor.motors} motors, not {len(params)}")
        self.hw = hw
        self.clock = hw.clock
        self.executor = executor
        self.lock = threading.RLock()
        self.wake = threading.Event()
        self.listeners: list[Listener] = []
        self.motors = [
            Motor(i, p, hw.steppers[i].driver, executor, self._notify)
            for i, p in enumerate(params)
        ]
        self.dc = DcMotor(hw.dc) if hw.dc is not None else None
        self.driver_poll_s = driver_poll_s
        self._next_poll = self.clock.now() + driver_poll_s
        self._next_plan = float("inf")
        self.executor_died: str | None = None
        self.planner_progress = 0
        self.monitor_progress = 0
        self.driver_errors = 0
        executor.on_event = self.wake.set
        self._running = False
        self._threads: list[threading.Thread] = []

    # -- notifications -------------------------------------------------------
    def _notify(self, motor: Motor, event: str) -> None:
        for listener in self.listeners:
            listener(motor, event)
        self.wake.set()

    @property
    def any_active(self) -> bool:
        return any(m.active or m.stopping for m in self.motors) or (
            self.dc is not None and self.dc.running
        )

    # -- commands (callers hold self.lock) -------------------------------------
    def dc_run(self, forward: bool, duration_s: float, end: BridgeState) -> None:
        if self.dc is None:
            raise LookupError("no DC motor")
        self.dc.run(forward, duration_s, end, self.clock.now())
        self.wake.set()

    # -- the planner's side (lock held) ------------------------------------------
    def process_events(self, now: float) -> None:
        """Hand what the executor reported to the motors."""
        for ev in self.executor.events():
            self._dispatch(ev, now)

    def _dispatch(self, ev: ExecEvent, now: float) -> None:
        if ev.kind is ExecEventKind.DIED:
            if self.executor_died is None:
                self.executor_died = ev.detail
                log.error("%s: every motor faults, positions lost", ev.detail)
            for m in self.motors:
                m.on_event(ev, now)
            return
        if ev.kind in (ExecEventKind.TIMING_LOST, ExecEventKind.FAULT):
            log.error("motor %d: %s %s", ev.motor, ev.kind.value, ev.detail)
        self.motors[ev.motor].on_event(ev, now)

    def service(self, now: float) -> float:
        """Events, segment refills, DC; returns when next due (lock held)."""
        self.process_events(now)
        nxt = self.executor.service(now)
        if self.dc is not None:
            self.dc.service(now)
            if self.dc.deadline is not None:
                nxt = min(nxt, self.dc.deadline)
        self.process_events(now)
        self._next_plan = nxt
        return nxt

    def poll_drivers(self, now: float) -> None:
        """Read every driver (outside the lock: SPI may block), then act under the lock."""
        statuses: list[DriverStatus | None] = []
        for m in self.motors:
            try:
                statuses.append(m.driver.status())
            except HalError as exc:
                self.driver_errors += 1
                statuses.append(None)
                log.error("motor %d: driver status read failed: %s", m.index, exc)
        with self.lock:
            for m, st in zip(self.motors, statuses, strict=True):
                if st is not None:
                    m.on_driver_status(st, now)
            self.service(now)

    # -- a virtual clock ------------------------------------------------------------
    def next_deadline(self) -> float:
        best = min(self._next_plan, self._next_poll)
        step = self.executor.next_deadline()
        if step is not None and step < best:
            best = step
        return best

    def _tick(self, now: float) -> None:
        self.executor.advance(now)
        self.service(now)
        if now >= self._next_poll:
            self._next_poll = now + self.driver_poll_s
            self.poll_drivers(now)

    def run_until(self, t: float) -> None:
        """Drive a virtual clock to ``t``, doing everything due on the way, in time order."""
        clock = self.clock
        if not isinstance(clock, VirtualClock):
            raise TypeError("run_until needs a VirtualClock")
        with self.lock:
            self.service(clock.now())
            while True:
                d = self.next_deadline()
                if d > t:
                    break
                clock.advance_to(_on_tick(d))
                self._tick(clock.now())
            clock.advance_to(t)
            self.service(clock.now())

    def run_until_idle(self, limit_s: float = 600.0) -> None:
        """Virtual clock: run until no motor moves and no DC run is on (or ``limit_s``)."""
        clock = self.clock
        if not isinstance(clock, VirtualClock):
            raise TypeError("run_until_idle needs a VirtualClock")
        end = clock.now() + limit_s
        with self.lock:
            self.service(clock.now())
            while self.any_active or any(m.queue for m in self.motors):
                d = self.next_deadline()
                if d > end:
                    raise TimeoutError("motion did not finish")
                clock.advance_to(_on_tick(d))
                self._tick(clock.now())

    # -- a real clock: the planner thread and the driver monitor ------------------------
    def start(self) -> None:
        if self.clock.is_virtual:
            raise ValueError("the engine's threads run on a real clock; tests use run_until")
        self._running = True
        self._threads = [
            threading.Thread(target=self._planner, name="motorctl-planner", daemon=True),
            threading.Thread(target=self._monitor, name="motorctl-drivers", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def stop_threads(self) -> None:
        self._running = False
        self.wake.set()
        for t in self._threads:
            t.join()
        self._threads = []

    @property
    def hardware_errors(self) -> int:
        """Backend calls that failed: driver reads here, STEP/DIR/end-stop I/O in the executor."""
        return self.driver_errors + self.executor.health().counters.get("io_errors", 0)

    @property
    def threads_alive(self) -> bool:
        return bool(self._threads) and all(t.is_alive() for t in self._threads)

    def _planner(self) -> None:
        clock, wake = self.clock, self.wake
        while self._running:
            self.planner_progress += 1
            with self.lock:
                nxt = self.service(clock.now())
            wait = min(nxt - clock.now(), PLANNER_TICK_S)
            if wait > 0 and wake.wait(wait):
                wake.clear()

    def _monitor(self) -> None:
        stop = threading.Event()
        while self._running:
            self.monitor_progress += 1
            self.poll_drivers(self.clock.now())
            stop.wait(self.driver_poll_s)

    def shutdown(self) -> None:
        """Soft-stop every motor (callers then wait until idle), brake the DC motor."""
        with self.lock:
            now = self.clock.now()
            for m in self.motors:
                m.stop(hard=False, now=now)
            if self.dc is not None:
                self.dc.stop(BridgeState.BRAKE)
            self.wake.set()
