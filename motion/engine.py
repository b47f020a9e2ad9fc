"""The motion engine: every motor's state machine, the DC motor and one executor.

Owner: ``engine.lock`` (the motion lock), taken by the dispatcher and the planner thread
for short, bounded work (state machines, planning a few ms of steps). The step path never
takes it: it is the executor's, fed through queues.

Threads on a real clock (:meth:`start`): the planner thread (events from the executor and
the drivers, refilling step segments, DC run ends; normal priority), and the HAL's driver
poller's (``Hardware.poller``, hal/poller.py: it reads the driver chips outside the lock
and pushes a fault or a stall here, :meth:`_on_driver_news`: queued, the planner woken, and
acted on under the lock by :meth:`process_events` at once, or by the dispatcher's
:meth:`catch_up` before it answers a command). Tests on a virtual clock call
:meth:`run_until` instead: executor steps, planner, DC and driver polls in time order.

:meth:`settle_stop` is called by the link thread WITHOUT the lock: it waits, bounded by
``stop_confirm_s``, for the executor to confirm a hard stop, taking the lock only to process
events, so the planner and the driver poller go on meanwhile. What wakes it is
``_reports``, a condition notified on every executor report (``Executor.on_event``: the
executor's event thread, or the step thread of the ``thread`` kind, for a moment).
"""

from __future__ import annotations

import enum
import logging
import threading
from collections import Counter, deque
from collections.abc import Callable, Sequence
from functools import partial

from motorctl.hal.interfaces import BridgeState, DriverStatus, Hardware, StepperDriver, VirtualClock
from motorctl.motion.dc import DcMotor
from motorctl.motion.executors.base import (
    STOP_CONFIRM_S,
    ExecEvent,
    ExecEventKind,
    Executor,
    from_ticks,
    to_ticks,
)
from motorctl.motion.motor import Motor
from motorctl.motion.types import MotorParams

log = logging.getLogger("motorctl.engine")


def _on_tick(t: float) -> float:
    """A virtual clock only stops on the step path's ticks, so edges land on their times."""
    return from_ticks(to_ticks(t))


Listener = Callable[[Motor, str], None]
#: the planner thread wakes at least this often (its progress is part of health; everything
#: it acts on wakes it: executor reports, commands, top-up and DC deadlines). Each pass, even
#: an empty one, costs about 20 us of a cold interpreter against the link thread: every 5 ms
#: they were 200 a second for nothing
PLANNER_TICK_S = 0.05
#: the status's percentiles of those waits are over the latest this many
STOP_WAITS_KEPT = 1024


class Settled(enum.Enum):
    """How :meth:`MotionEngine.settle_stop` ended."""

    CONFIRMED = "confirmed"  # the executor confirmed: the motor's position is final
    TIMED_OUT = "timed_out"  # no confirmation within the deadline (a stalled executor)
    SKIPPED = "skipped"  # not waited for: a stop whose wait timed out is still unconfirmed
    DIED = "died"  # the executor is dead: the motor is faulted, its position lost


class ChangeLock:
    """The motion lock: a re-entrant lock that counts its releases. Every change of a
    motor's state, its queue, a fault, a stop or the DC motor is made under it, so
    ``releases`` moves on after each such change is whole: a reader that saw the same count
    before and after looking (without the lock) saw no change since (the status server's
    documents, daemon/status/document.py). Any thread; ``releases`` is only written with
    the lock held."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self.releases = 0

    def __enter__(self) -> ChangeLock:
        self._lock.acquire()
        return self

    def __exit__(self, kind: object, exc: object, tb: object) -> None:
        self.releases += 1
        self._lock.release()


class MotionEngine:
    def __init__(
        self,
        hw: Hardware,
        params: Sequence[MotorParams],
        executor: Executor,
        *,
        stop_confirm_s: float = STOP_CONFIRM_S,
    ) -> None:
        if len(params) != len(hw.steppers):
            raise ValueError(f"{len(params)} motors configured, hardware has {len(hw.steppers)}")
        if executor.motors != len(params):
            raise ValueError(f"the executor drives {executor.motors} motors, not {len(params)}")
        self.hw = hw
        self.clock = hw.clock
        self.executor = executor
        self.lock = ChangeLock()
        self.wake = threading.Event()
        self.listeners: list[Listener] = []
        self.motors = [
            Motor(i, p, hw.steppers[i].driver, executor, self._notify) for i, p in enumerate(params)
        ]
        self.dc = DcMotor(hw.dc) if hw.dc is not None else None
        self.stop_confirm_s = stop_confirm_s
        self._next_plan = float("inf")
        self.executor_died: str | None = None
        self.planner_progress = 0
        # what the driver poller pushed (its thread appends, process_events takes: a deque's
        # append and popleft are atomic, no lock between them)
        self.poller = hw.poller
        # each reading with every motor's step counter just before its pass read the drivers
        self._driver_news: deque[tuple[StepperDriver, DriverStatus, tuple[int, ...]]] = deque()
        self._steps_before_poll: tuple[int, ...] = ()
        self.poller.connect(self._on_driver_news, self._before_poll)
        # executor reports (on_event calls) so far: what wakes a waiting settle_stop
        self._reports = threading.Condition(threading.Lock())
        self._report_count = 0
        # (motor, its stops_settled) when a wait timed out: skip waits until that changes
        self._stalled: list[tuple[Motor, int]] = []
        #: how the hard stops' confirmation waits ended; how long the latest ones took
        self.stop_waits: Counter[str] = Counter(dict.fromkeys((s.value for s in Settled), 0))
        self.stop_wait_times: deque[float] = deque(maxlen=STOP_WAITS_KEPT)
        self.stop_wait_max_s = 0.0
        self.stop_wait_sum_s = 0.0
        executor.on_event = self._on_executor_event
        self._running = False
        self._threads: list[threading.Thread] = []

    # -- notifications -------------------------------------------------------
    def _on_executor_event(self) -> None:
        """Events are pending (any thread; cheap: never the engine lock, only the moment
        ``_reports`` takes)."""
        self.wake.set()
        with self._reports:
            self._report_count += 1
            self._reports.notify_all()

    def _before_poll(self) -> None:
        """The poller is about to read the drivers (its thread): each motor's step counter
        now, for the readings of this pass (a lock-free read of the executor's count)."""
        self._steps_before_poll = tuple(m.abs_steps for m in self.motors)

    def _on_driver_news(self, readings: Sequence[tuple[StepperDriver, DriverStatus]]) -> None:
        """A driver read a fault or a stall (the poller's thread; never the engine lock):
        queued, and the planner woken to act on it now."""
        steps = self._steps_before_poll
        self._driver_news.extend((driver, status, steps) for driver, status in readings)
        self.wake.set()

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

    def fault_stop_moving(
        self, reason: str, hard: bool, now: float, cause: str = "other"
    ) -> list[str]:
        """Every motor in motion stops (``hard``: at once; else along its ramp) and latches
        ``reason`` (:meth:`Motor.fault_stop`); a running DC motor brakes (it has no fault to
        latch). What was stopped, named for a log line. (The host's silence, [link]
        timeout_ms.)"""
        stopped = [
            f"motor {m.index} ({m.params.name})"
            for m in self.motors
            if m.fault_stop(reason, now, hard=hard, cause=cause)
        ]
        if self.dc is not None and self.dc.running:
            self.dc.stop(BridgeState.BRAKE)
            stopped.append("the DC motor (braked)")
        self.wake.set()
        return stopped

    # -- a hard stop's confirmation (the link thread, WITHOUT the lock) -------------------
    def settle_stop(self, motor: Motor, timeout_s: float | None = None) -> Settled:
        """Wait until ``motor``'s hard stop has taken effect in the executor, at most
        ``timeout_s`` (default ``stop_confirm_s``); the confirming event is processed here,
        so the motor is idle (or whatever followed the stop) on return.

        Never waits while the executor is dead, nor while a stop whose wait timed out is
        still unconfirmed (the executor is evidently stalled: a burst of StopMoves to it
        waits once, not once each).

        On a virtual clock the wait lets virtual time pass: everything due runs in time
        order (as :meth:`run_until`) until the stop is confirmed or the deadline is reached.
        """
        if timeout_s is None:
            timeout_s = self.stop_confirm_s
        start = self.clock.now()
        with self.lock:
            result = self._settle_check(motor, start)
            if result is None:
                self._stalled = [(m, n) for m, n in self._stalled if m.stops_settled == n]
                if self._stalled:
                    result = Settled.SKIPPED
        if result is None:
            if self.clock.is_virtual:
                result = self._settle_virtual(motor, start + timeout_s)
            else:
                result = self._settle(motor, start + timeout_s)
        waited = self.clock.now() - start
        with self.lock:
            if result is Settled.TIMED_OUT:
                self._stalled.append((motor, motor.stops_settled))
            self.stop_waits[result.value] += 1
            self.stop_wait_times.append(waited)
            self.stop_wait_max_s = max(self.stop_wait_max_s, waited)
            self.stop_wait_sum_s += waited
        return result

    def stop_wait_status(self) -> dict[str, object]:
        """A snapshot (any thread): how hard stops' confirmation waits ended, how long."""
        out: dict[str, object] = dict(self.stop_waits)
        times = sorted(self.stop_wait_times)  # one C-level copy: no torn read, no lock

        def pct(q: float) -> float:
            return round(times[min(len(times) - 1, int(q * len(times)))] * 1e6, 1)

        out.update(
            waits=sum(self.stop_waits.values()),
            wait_p50_us=pct(0.5) if times else 0.0,
            wait_p99_us=pct(0.99) if times else 0.0,
            wait_max_us=round(self.stop_wait_max_s * 1e6, 1),
            wait_sum_us=round(self.stop_wait_sum_s * 1e6, 1),
        )
        return out

    def _settle_check(self, motor: Motor, now: float) -> Settled | None:
        """Lock held: process what the executor reported; the outcome if there is one."""
        self.process_events(now)
        if not motor.stopping:
            return Settled.CONFIRMED
        if self.executor_died is not None:
            return Settled.DIED
        return None

    def _settle(self, motor: Motor, deadline: float) -> Settled:
        """A real clock: sleep until the executor reports something, then look again."""
        clock, reports = self.clock, self._reports
        while True:
            with reports:
                seen = self._report_count
            with self.lock:
                done = self._settle_check(motor, clock.now())
            if done is not None:
                return done
            left = deadline - clock.now()
            if left <= 0:
                return Settled.TIMED_OUT
            with reports:
                reports.wait_for(partial(self._reported_since, seen), left)

    def _reported_since(self, seen: int) -> bool:
        return self._report_count != seen

    def _settle_virtual(self, motor: Motor, deadline: float) -> Settled:
        """A virtual clock: run what is due, in time order, up to the deadline."""
        clock = self.clock
        assert isinstance(clock, VirtualClock)
        with self.lock:
            while True:
                d = self.next_deadline()
                if d > deadline:
                    clock.advance_to(deadline)
                    self.service(clock.now())
                else:
                    clock.advance_to(_on_tick(d))
                    self._tick(clock.now())
                done = self._settle_check(motor, clock.now())
                if done is not None:
                    return done
                if clock.now() >= deadline:
                    return Settled.TIMED_OUT

    # -- the planner's side (lock held) ------------------------------------------
    def process_events(self, now: float) -> None:
        """Hand what the drivers and the executor reported to the motors."""
        news = self._driver_news
        while news:
            driver, status, steps = news.popleft()
            for m in self.motors:
                if m.driver is driver:
                    m.on_driver_status(status, now, steps[m.index] if steps else None)
        for ev in self.executor.events():
            self._dispatch(ev, now)

    def catch_up(self) -> None:
        """Lock held: :meth:`process_events`, when anything was reported (the dispatcher,
        before each command). A cheap look first, for the usual command meets nothing: the
        driver poller's queue (a deque: its append is atomic) and the executor's
        (:meth:`~motorctl.motion.executors.base.Executor.events_waiting`, the same stores
        ``events`` reads). What was published before the look is processed before the
        command, as it was when every command asked for the events themselves."""
        if self._driver_news or self.executor.events_waiting():
            self.process_events(self.clock.now())

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

    # -- a virtual clock ------------------------------------------------------------
    def next_deadline(self) -> float:
        best = min(self._next_plan, self.poller.next_due())
        step = self.executor.next_deadline()
        if step is not None and step < best:
            best = step
        return best

    def _tick(self, now: float) -> None:
        """What is due at ``now``: steps, the driver polls (what they read is acted on in
        the service that follows), the planner."""
        self.executor.advance(now)
        if self.poller.is_due(now):
            self.poller.poll_due(now)
        self.service(now)

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

    # -- a real clock: the planner thread and the driver poller's -----------------------
    def start(self) -> None:
        if self.clock.is_virtual:
            raise ValueError("the engine's threads run on a real clock; tests use run_until")
        self._running = True
        self._threads = [
            threading.Thread(target=self._planner, name="motorctl-planner", daemon=True),
        ]
        for t in self._threads:
            t.start()
        self.poller.start()

    def stop_threads(self) -> None:
        self.poller.stop()
        self._running = False
        self.wake.set()
        for t in self._threads:
            t.join()
        self._threads = []

    @property
    def hardware_errors(self) -> int:
        """Backend calls that failed: driver polls that raised (the poller's), STEP/DIR/end-stop
        I/O in the executor."""
        return self.poller.failures + self.executor.health().counters.get("io_errors", 0)

    @property
    def threads_alive(self) -> bool:
        return (
            bool(self._threads) and all(t.is_alive() for t in self._threads) and self.poller.alive
        )

    def _planner(self) -> None:
        clock, wake = self.clock, self.wake
        while self._running:
            self.planner_progress += 1
            with self.lock:
                nxt = self.service(clock.now())
            wait = min(nxt - clock.now(), PLANNER_TICK_S)
            if wait > 0 and wake.wait(wait):
                wake.clear()

    def shutdown(self) -> None:
        """Soft-stop every motor (callers then wait until idle), brake the DC motor."""
        with self.lock:
            now = self.clock.now()
            for m in self.motors:
                m.stop(hard=False, now=now)
            if self.dc is not None:
                self.dc.stop(BridgeState.BRAKE)
            self.wake.set()
