"""The step planner: the half of a step executor that cuts plans into step segments.

:class:`StepExecutor` is the planner half of the STEP/DIR executors: it walks each motor's
trajectory a little ahead of time (``ahead_s``), cuts the steps into segments in closed
form (:class:`~motorctl.motion.executors.segments.SegmentCutter`) and hands them to a step
core (``step_core.py``, or its compiled twin). How they reach the core is the transport,
the one thing each kind implements (three abstract methods, :meth:`StepExecutor._push`,
:meth:`StepExecutor._push_stop` and :meth:`StepExecutor._raw_events`, and one optional,
:meth:`StepExecutor._sync`):

- ``thread.py``, :class:`~motorctl.motion.executors.thread.ThreadStepExecutor` (kind
  ``thread``): the core's inbox deques, in a thread of the daemon or, on a virtual clock,
  no thread at all;
- ``process/parent.py``,
  :class:`~motorctl.motion.executors.process.parent.ProcessStepExecutor` (kind
  ``process``): the rings of a block of shared memory, to a process of its own.

Threads: the daemon's planner side only (the engine's lock held: commands and
:meth:`StepExecutor.service`); it reads the core's per-motor cells (``motor_cells``) as
snapshots and never waits for the core.
"""

from __future__ import annotations

from abc import abstractmethod
from collections import deque
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Final

from motorctl.hal.interfaces import Clock
from motorctl.motion.executors.base import (
    AxisLimits,
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
    from_ticks,
    to_ticks,
)
from motorctl.motion.executors.core_cells import (
    ABSORBED,
    LAG_FAULTS,
    LAG_UNIT,
    MOTOR_CELLS,
    SHIFT,
    WORST_LAG,
    WORST_LATE,
)
from motorctl.motion.executors.segments import Boundary, SegmentCutter, StepSegment
from motorctl.motion.latency import Cells
from motorctl.motion.profile import Trajectory
from motorctl.motion.types import MotorParams, Ramp

K = ExecEventKind
#: the planner tops up the handed-over steps once this much of the horizon has been used
#: (at most half of it): every motor in one pass (one cold start of the interpreter's
#: caches, one hold of the GIL against the link thread) 50 times a second; every 5 ms made
#: the IsReady round trip's p99 worse (docs/timing.md)
REFILL_S = 0.020
#: how far ahead steps are handed to the core ([step_thread] ahead_ms declares it with this
#: value). 50 ms, not 20: the planner is a normal thread of the daemon, and a pass that comes
#: late (the GIL held by the link thread, a busy core, a collection) must not leave the
#: core without steps, which would stop a motor with "step timing lost"; with a top-up every
#: REFILL_S, 30 ms of such lateness are covered, and a soft stop or a new speed still takes
#: over within lead_s + span_s, as the handed-over plan is cut (docs/timing.md)
AHEAD_S: Final = 0.05
#: how soon after a re-plan's command the running plan may be cut ([step_thread] lead_ms
#: declares it with this value): the re-plan must reach the core before the segment at the
#: cut begins, or the motor stops with "step timing lost (re-plan came N us late)"; 3 ms
#: covers the planner's pass and the hand-over on a loaded board (docs/timing.md)
LEAD_S: Final = 0.003
_SELF_STOPS = (K.ENDSTOP, K.RELEASED, K.TIMING_LOST, K.FAULT)


def axis_limits(
    params: Sequence[MotorParams],
    max_error_s: float,
    *,
    slide_after_s: float = 100e-6,
    lag_faults: bool = True,
) -> list[AxisLimits]:
    """Each motor's fail-safe bounds: spacing from its maximum speed less the step error;
    lateness judged by its lag in full steps (``lag_faults`` False: a simulated motor)."""
    return [
        AxisLimits(
            min_interval_s=max(1.0 / p.max_speed - max_error_s, 0.0) * (1 - 1e-9),
            pulse_s=p.pulse_s,
            debounce_s=p.debounce_s,
            slide_after_s=slide_after_s,
            microsteps=p.microsteps,
            start_speed=p.start_speed,
            max_lag_full_steps=p.max_lag_full_steps,
            lag_faults=lag_faults,
        )
        for p in params
    ]


class _Plan:
    """One motor's plan as the planner walks it."""

    def __init__(self) -> None:
        self.gen = -1
        self.traj: Trajectory | None = None  # while steps remain to be handed over
        self.cutter: SegmentCutter | None = None
        self.handed: Trajectory | None = None  # the plan whose steps were handed over
        self.bounds: deque[Boundary] = deque()  # where handed-over segments start
        self.cut: Boundary | None = None  # where committed() cut the plan (for follow)
        self.until = float("-inf")  # steps up to this time have been handed over
        self.counter = 0  # the step counter after the last step handed over
        self.last_t = float("-inf")  # time of the last step handed over
        self.busy = False  # handed-over steps of this plan may remain to be executed
        self.watch = True  # the core watches the end stop ahead
        self.release = False  # and the end stop behind for its release

    def forget(self) -> None:
        """Nothing of the current plan is left to cut (stopped, done, replaced)."""
        self.traj = self.cutter = self.handed = self.cut = None
        self.bounds.clear()


class StepExecutor(Executor):
    """Plans into segments; the transport to the core it feeds is the subclass's (the
    ``_push``, ``_push_stop`` and ``_raw_events`` hooks; ``_sync`` where it can).

    ``ahead_s``: how far ahead steps are handed over. 0: exactly one step ahead, and a
    re-plan flushes that step (only where the core can be synchronised at once, i.e. on a
    virtual clock: tests then see re-plans take effect at once). ``lead_s``: how far ahead
    of "now" a motor at rest starts, and how soon after "now" a re-plan may cut the running
    plan (covers the core's wake-up). ``max_error_s``: the segments' step time error bound.
    ``span_s``: no segment is longer, so that a re-plan (a soft stop, a new speed) takes
    over within ``lead_s + span_s`` of the command instead of after everything handed over.
    """

    def __init__(
        self,
        clock: Clock,
        limits: Sequence[AxisLimits],
        *,
        ahead_s: float = AHEAD_S,
        lead_s: float = LEAD_S,
        max_error_s: float = 5e-6,
        span_s: float = 0.002,
    ) -> None:
        super().__init__(len(limits))
        self.clock = clock
        self.limits = list(limits)
        self.ahead_s = ahead_s
        self.lead_s = lead_s
        self.max_error = to_ticks(max_error_s)
        self.span = to_ticks(span_s)
        self.plans = [_Plan() for _ in limits]
        #: the core's per-motor cells (its shift, late-step figures): a subclass hands these
        #: to its core, or puts the core's own (shared memory) in their place
        self.motor_cells: Cells = [0] * (len(limits) * MOTOR_CELLS)

    def shift(self, motor: int) -> float:
        """How far the core has slid the motor's schedule (s): the motor's own time is the
        clock's less this. Plans are made on the motor's own time (the core adds it back)."""
        return from_ticks(self.motor_cells[motor * MOTOR_CELLS + SHIFT])

    def motor_time(self, motor: int, now: float) -> float:
        return now - self.shift(motor)

    def motor_timing(self, motor: int) -> dict[str, Any]:
        c = self.motor_cells
        b = motor * MOTOR_CELLS
        return {
            "late_absorbed": int(c[b + ABSORBED]),
            "slid_ms": round(c[b + SHIFT] / 1e6, 3),
            "worst_late_us": round(c[b + WORST_LATE] / 1e3, 1),
            "worst_lag_full_steps": round(c[b + WORST_LAG] / LAG_UNIT, 4),
            "lag_faults": int(c[b + LAG_FAULTS]),
        }

    # -- the transport (each kind's own) ----------------------------------------------
    @abstractmethod
    def _push(self, motor: int, segments: list[StepSegment]) -> None:
        """Hand ``segments`` (the motor's next, in order) to the core and wake it; never
        blocks (what does not fit yet goes later, in order)."""

    @abstractmethod
    def _push_stop(self, motor: int, gen: int, cut: int = -1) -> None:
        """Have the core drop the motor's segments of ``gen`` and older and report STOPPED
        (a hard stop); with ``cut`` >= 0 only those that start at or after tick ``cut``,
        silently (a re-plan takes over there). Never blocks."""

    @abstractmethod
    def _raw_events(self) -> list[ExecEvent]:
        """The core's events since the last call (and DIED once, if the core is gone)."""

    def _sync(self) -> bool:
        """Let the core apply pending stops now if it can (a virtual clock): True if done,
        False where the core runs on its own (the stop's STOPPED event follows)."""
        return False

    # -- the seam ------------------------------------------------------------------------
    def committed(self, motor: int, now: float) -> Committed:
        own = self.motor_time(motor, now)
        c = self._committed(motor, own)
        return replace(c, after=c.t - own)

    def _committed(self, motor: int, now: float) -> Committed:
        """committed() on the motor's own (slid) time ``now``."""
        p = self.plans[motor]
        if self.ahead_s == 0:  # a re-plan flushes the one step handed over: start from now
            c = self.position(motor)
            if p.traj is None:
                return Committed(now, float(c), 0.0, c)
            s = min(max(p.traj.position(now), c - 0.999), c + 0.999)
            return Committed(now, s, p.traj.velocity(now), c)
        p.cut = None
        if p.handed is not None and p.busy:
            # cut the running plan at the first segment that starts after the lead: the
            # steps before it are made as planned, the new plan takes over from there
            bounds = p.bounds
            soonest = to_ticks(now + self.lead_s)
            while bounds and bounds[0].tick < soonest:
                bounds.popleft()
            if bounds:
                b = p.cut = bounds[0]
                s = min(max(p.handed.position(b.t), b.counter - 0.999), b.counter + 0.999)
                return Committed(b.t, s, p.handed.velocity(b.t), b.counter)
        if p.traj is None or p.cutter is None:
            t = max(now + self.lead_s, p.last_t) if p.busy else now + self.lead_s
            return Committed(t, float(p.counter), 0.0, p.counter)
        t = max(now, p.until)
        s = p.traj.position(t)
        lo, hi = p.counter - 0.999, p.counter + 0.999
        return Committed(t, min(max(s, lo), hi), p.traj.velocity(t), p.counter)

    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        p = self.plans[motor]
        busy = p.busy  # steps of the plan being replaced may remain to be made
        if self.ahead_s == 0 and busy:
            self._push_stop(motor, p.gen)  # flush the step handed over but not yet made
            self._sync()
            p.counter = self.position(motor)
            busy = False
        cut = p.cut
        if cut is not None and busy:  # committed() cut the running plan there
            self._push_stop(motor, p.gen, cut.tick)
            p.counter, p.last_t, p.until = cut.counter, cut.prev_t, cut.t
        p.forget()
        p.gen = gen
        p.traj = traj
        p.handed = traj
        p.cutter = SegmentCutter(traj.segments, p.counter, self.max_error, self.span)
        p.until = max(p.until, traj.start_time)
        if p.cutter.done:
            p.forget()
            if busy:  # no step of its own, but the old plan's are still to come: DONE after
                self._push(motor, [StepSegment(to_ticks(p.until), 0, 0, 0, 0, gen, True)])
                return True
            p.busy = False
            return False
        p.busy = True
        p.watch = endstops
        p.release = release
        self._feed(motor, self.motor_time(motor, self.clock.now()))
        return True

    def stop(self, motor: int, gen: int) -> int | None:
        p = self.plans[motor]
        p.gen = gen
        p.forget()
        p.busy = False
        self._push_stop(motor, gen)
        if self._sync():
            pos = self.position(motor)
            p.counter = pos
            p.until = p.last_t = self.motor_time(motor, self.clock.now())
            return pos
        return None

    def planned(self, motor: int) -> bool:
        return self.plans[motor].busy

    def _feed(self, motor: int, now: float) -> None:
        """Hand over the motor's steps up to ``now + ahead_s`` (at least the next one);
        ``now`` on the motor's own time."""
        p = self.plans[motor]
        cutter = p.cutter
        if cutter is None:
            return
        horizon = now + self.ahead_s
        out = cutter.cut(horizon, p.gen, p.watch, p.bounds if self.ahead_s else None, p.release)
        p.counter = cutter.counter
        p.last_t = from_ticks(to_ticks(cutter.last_t))  # on the step path's ticks
        done = out[-1].last if out else cutter.done
        p.until = max(p.until, p.last_t if done else max(horizon, p.last_t))
        if done:
            p.traj = p.cutter = None
        if out:
            self._push(motor, out)

    def service(self, now: float) -> float:
        """Top up every motor's handed-over steps to the horizon once ``REFILL_S`` of it has
        been used, all motors in the same pass: each pass holds the daemon's GIL against the
        link thread and starts on a cold interpreter, so few passes are better than many
        (docs/timing.md)."""
        nxt = float("inf")
        # each motor's plan is on its own time: the clock's less its shift (slid schedule)
        if self.ahead_s == 0:  # one step ahead: the next once the last one is made
            for m, p in enumerate(self.plans):
                shift = self.shift(m)
                if p.cutter is not None and p.last_t + shift <= now + 1e-9:  # (ticks)
                    self._feed(m, now - shift)
                if p.cutter is not None:
                    nxt = min(nxt, p.last_t + shift)
            return nxt
        used = min(self.ahead_s / 2, REFILL_S)
        keep = self.ahead_s - used  # handed over, still to come
        shifts = [self.shift(m) for m in range(len(self.plans))]
        # once one motor is due, every motor that would be due before the next top-up is
        # topped up with it: one pass for all (cold caches once, one hold of the GIL against
        # the link thread), not one pass per motor a little apart
        if any(
            p.cutter is not None and p.until + shift - keep <= now + 1e-9
            for p, shift in zip(self.plans, shifts, strict=True)
        ):
            for m, p in enumerate(self.plans):
                if p.cutter is not None and p.until + shifts[m] - keep <= now + used:
                    self._feed(m, now - shifts[m])
        for p, shift in zip(self.plans, shifts, strict=True):
            if p.cutter is not None:
                nxt = min(nxt, p.until + shift - keep)  # (on a clock of ticks)
        return nxt

    def events(self) -> list[ExecEvent]:
        out = self._raw_events()
        for ev in out:
            if ev.motor < 0:
                continue
            p = self.plans[ev.motor]
            if ev.kind in _SELF_STOPS or (ev.kind is K.STOPPED and ev.gen == p.gen):
                p.forget()
                p.busy = False
                p.counter = ev.position
                p.until = p.last_t = self.motor_time(ev.motor, max(ev.t, self.clock.now()))
            elif ev.kind is K.DONE and ev.gen == p.gen:
                p.forget()
                p.busy = False
                p.counter = ev.position
        return out
