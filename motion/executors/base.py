"""The executors' contract: what carries out the motion the motor state machines plan.

An :class:`Executor` turns each motor's planned :class:`~motorctl.motion.profile.Trajectory`
into motion and reports what really happened. The motor state machines (``motion/motor.py``)
and the engine (``motion/engine.py``) know this module only (tests/test_imports.py keeps it
so); the implementations are the rest of this folder, each in its own module:

- timed STEP/DIR edges: ``planner.py`` (the planner half, in the daemon's process) cuts
  each trajectory into Klipper-style step segments (``segments.py``) a few milliseconds
  ahead and feeds them to a step core (``step_core.py``, the hot loop, or its compiled twin
  ``compiled_core.py`` over ``csrc/``), which owns the STEP/DIR and end-stop lines and runs
  in a thread (``thread.py``, kind ``thread``) or a process of its own (kind ``process``:
  ``process/parent.py`` in the daemon, ``process/child.py`` in the process that
  ``process/start.py`` starts, the shared block's ``process/rings.py`` between them);
- a driver chip that runs its own ramp (``chip_ramp.py``: TMC5160 motion-controller mode,
  through the HAL's :class:`~motorctl.hal.interfaces.RampDriver` capability): ``follow``
  maps to the chip's target, speed and ramps, ``position`` is its step counter;
- ``split.py``: one seam over both, each motor to the executor that moves it.

Threads: the methods are called by the motion engine with its lock held (the command and
planner side), except :meth:`Executor.position`, :meth:`Executor.health`,
:meth:`Executor.step_lateness` and :meth:`Executor.endstop_active`, which read snapshots and
may be called from any thread without a lock. No method blocks on the step path or waits for it.
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from motorctl.motion.latency import LatencyStats
from motorctl.motion.profile import Trajectory
from motorctl.motion.rt import RealtimeReport
from motorctl.motion.types import MotorParams, Ramp

#: Integer time of the step path: nanoseconds of the executor's clock.
TICKS_PER_S = 1_000_000_000
#: How long a hard StopMove's answer waits (in the engine) for the executor to confirm that
#: the motor has stopped (its position final), by default (config: step_thread.stop_confirm_ms).
#: The step core applies a stop within one loop iteration, so this is normally well under a
#: millisecond; the bound only matters for an executor that is stalled (not scheduled,
#: SIGSTOPped) or dead. See docs/protocol.md, "StopMove".
STOP_CONFIRM_S = 0.05


def to_ticks(t: float) -> int:
    return round(t * TICKS_PER_S)


def from_ticks(ticks: int) -> float:
    return ticks / TICKS_PER_S


class ExecEventKind(enum.Enum):
    DONE = "done"  # a finite plan's last step was executed: ``position`` is final
    STOPPED = "stopped"  # a stop() took effect: ``position`` is final
    ENDSTOP = "endstop"  # the executor stopped the axis itself at an end stop
    TIMING_LOST = "timing_lost"  # a late step would have lagged beyond the tolerance: stopped
    FAULT = "fault"  # the axis's hardware failed (HalIOError): stopped
    DIED = "died"  # the executor itself is gone (motor -1: every motor)
    # the executor stopped the axis itself where the end stop it backed off released
    # (a plan followed with ``release``): ``mark`` is where it released
    RELEASED = "released"


#: an ENDSTOP's ``detail`` when the end stop ahead was active before the motion's first step
#: toward it: the executor made no step (docs/protocol.md, "Faults and lost positions")
ENDSTOP_ALREADY_ACTIVE = "already active"


@dataclass(frozen=True)
class ExecEvent:
    """Something the executor did on its own or finished.

    ``gen`` is the generation of the plan the event belongs to; ``position`` the executed
    step counter when it happened; ``t`` its time (for ENDSTOP and RELEASED the kernel's
    timestamp of the edge); ``direction`` the end stop's side (+1 max, -1 min) or the
    motion's direction; ``speed`` the step rate (step/s) the motor had then; ``detail`` a
    human reason; ``mark`` (RELEASED only) the step counter where the end stop released: the
    first position off it, at or before ``position``.
    """

    kind: ExecEventKind
    motor: int
    gen: int
    position: int
    t: float
    direction: int = 0
    speed: float = 0.0
    detail: str = ""
    mark: int = 0


@dataclass(frozen=True)
class AxisLimits:
    """The fail-safe bounds of one motor, fixed when the executor is built.

    ``min_interval_s``: no two steps are ever emitted closer than this (the profile's bound:
    1 / the motor's maximum speed, less the planner's step error). ``pulse_s``: STEP high
    time. ``debounce_s``: an end stop counts once active this long, and released once
    inactive this long (by the kernel's edge timestamps).

    Lateness (docs/timing.md): a step later than ``slide_after_s`` after its planned time
    makes the rest of that motor's schedule slide by its lateness (the move takes that much
    longer; steps never bunch up to catch up). The lag it caused, lateness x step rate /
    ``microsteps``, in full steps, is judged as a motor would feel it: with ``lag_faults``
    and above ``start_speed`` (step/s), a lag beyond ``max_lag_full_steps`` stops the motor
    instead (TIMING_LOST: a real rotor may have slipped). Without ``lag_faults`` (a simulated
    motor has no rotor) every late step slides.
    """

    min_interval_s: float
    pulse_s: float = 2e-6
    debounce_s: float = MotorParams.debounce_s
    slide_after_s: float = 100e-6
    # the motor's own, always given (their defaults are the config model's: [[motors]])
    microsteps: int = field(kw_only=True)
    start_speed: float = field(kw_only=True)
    max_lag_full_steps: float = field(kw_only=True)
    lag_faults: bool = True

    def lag_rule(self) -> LagRule:
        return LagRule(self.microsteps, self.start_speed, self.max_lag_full_steps)


def lag_full_steps(late: float, gap: float, microsteps: int) -> float:
    """The lag, in full steps, of a motor whose step came ``late`` after its planned time
    while its steps are ``gap`` apart (its rate; both in one unit of time)."""
    return late / gap / microsteps


class LagRule:
    """The one rule for a late step (docs/timing.md, "Late steps: slide, or stop"): a motor
    moving faster than its ``start_speed`` (step/s) whose lag (:func:`lag_full_steps`) is
    beyond ``max_lag_full_steps`` may have lost steps, and is stopped; otherwise the move
    slides. The step core asks it of every late step (the compiled core's C mirrors it:
    csrc/core.c), ``motorctld --probe``'s platform check of the worst wake-up measured."""

    __slots__ = ("lag_k", "max_lag_full_steps", "microsteps", "start_gap", "start_speed")

    def __init__(self, microsteps: int, start_speed: float, max_lag_full_steps: float) -> None:
        self.microsteps = microsteps
        self.start_speed = start_speed
        self.max_lag_full_steps = max_lag_full_steps
        #: above the start speed: a step's planned gap shorter than this (ticks); a start
        #: speed of 1 step/s or less is any motion (a gap of 1 s or more is rest), and a
        #: tiny one would overflow the division
        self.start_gap = TICKS_PER_S if start_speed <= 1 else round(TICKS_PER_S / start_speed)
        #: lag (full steps) = late / gap / microsteps: beyond the tolerance when late > gap * this
        self.lag_k = max_lag_full_steps * microsteps

    def lag(self, late: float, gap: float) -> float:
        """:func:`lag_full_steps` for this motor (0 when it is not moving: ``gap`` of 1 s or
        more, or none)."""
        return lag_full_steps(late, gap, self.microsteps) if 0 < gap < TICKS_PER_S else 0.0

    def loses_steps(self, late: float, gap: float) -> bool:
        """A step ``late`` ticks after its time, ending a gap of ``gap`` ticks: True when it
        lagged the motor beyond its tolerance above its start speed."""
        return 0 < gap < TICKS_PER_S and gap < self.start_gap and late > gap * self.lag_k

    def loses_steps_at(self, late_s: float, rate: float) -> bool:
        """The same of a motor stepping at ``rate`` step/s, ``late_s`` seconds late."""
        return rate > 0 and self.loses_steps(late_s * TICKS_PER_S, TICKS_PER_S / rate)

    def fastest_safe_rate(self, late_s: float) -> float:
        """The step rate (step/s) above which a step ``late_s`` seconds late loses steps."""
        return max(self.start_speed, self.lag_k / late_s)


@dataclass(frozen=True)
class Committed:
    """Where a new plan for a motor must start: time, position (steps) and velocity.

    ``counter`` is the integer step counter there (``position`` is within 1 of it).
    """

    t: float
    position: float
    velocity: float
    counter: int
    #: how long after "now" (the command) the new plan takes over, s (steps handed to the
    #: executor before that point are still made)
    after: float = 0.0


@dataclass
class ExecutorHealth:
    """A snapshot: ``progress`` grows while the executor makes progress (also when idle)."""

    alive: bool
    progress: int
    reason: str | None = None
    counters: dict[str, int] = field(default_factory=dict)
    latency: dict[str, Any] = field(default_factory=dict)


class Executor(ABC):
    """The contract between the motor state machines and whatever moves the motors.

    Motors are indexed 0..n-1; positions are the executed step counter (an unbounded int,
    the state machines' ``abs_steps``); times are the executor's clock in seconds.

    Generations: every :meth:`follow` and :meth:`stop` carries ``gen``, increasing per motor.
    An event carries the generation of the plan it belongs to; the caller ignores DONE and
    STOPPED of generations it has replaced. When the executor stops an axis on its own (end
    stop, timing lost, fault) it drops everything for that axis, queued or arriving later,
    until the caller answers with :meth:`stop`: nothing planned before the caller saw the
    event moves the motor again.

    - :meth:`follow` starts executing ``traj`` (which begins at :meth:`committed`), replacing
      whatever was planned after that point. ``ramp`` is the ramp it was planned with, for
      executors that re-plan themselves (a chip's own ramp). ``endstops`` False: do not
      watch the end stops (stall homing drives into the stop). ``release`` True: also watch
      the end stop behind, the one the motion leaves (homing's back-off): once it has been
      inactive for ``debounce_s`` the executor stops the axis itself and reports RELEASED,
      with ``mark`` the step counter where it released (the first position off it; the
      axis may stand a few steps further on). Never blocks. Returns False when the plan
      makes no step (nothing to do: no DONE follows).
    - :meth:`stop` is a hard stop: after at most one step period nothing of older
      generations moves the motor. Returns the final position when already known, else None
      and a STOPPED event of ``gen`` follows with it. It is also the answer to an event by
      which the executor stopped an axis itself: until that answer, the executor drops every
      plan for the axis (one made before the caller saw the event would start from a wrong
      position).
    - :meth:`committed`: an executor that takes work ahead of time (step segments, a few ms)
      commits that far; a soft stop or a re-plan starts there.
    - End stops: the executor watches the end stop ahead of each step and stops the axis
      itself when it has been active for ``debounce_s``; it reports ENDSTOP with the position
      and time of the trigger. It looks before the first step too: a motion that starts
      toward an end stop active already makes no step; ENDSTOP says so (its ``detail``
      :data:`ENDSTOP_ALREADY_ACTIVE`, the position where it stands). Whether that ends a
      homing run or is a fault is the caller's business. A plan followed with ``release``
      ends the same way where the end stop behind releases (RELEASED).
    - Fail safe: steps are never closer than ``min_interval_s``; a late step slides the rest
      of the motor's schedule, unless the lag it causes is one a real motor may not survive
      (:class:`AxisLimits`): then the motor stops (TIMING_LOST, with the speed it had).
    - :meth:`service` does the caller-side work (refilling segments) and returns when it is
      next due; the engine's planner thread calls it (never the step path).
    - ``on_event`` is called, from any thread, when events are pending; it must be cheap.
    - If the executor itself dies, :meth:`events` reports DIED (motor -1) once and
      :meth:`health` says why; every motor is then to be treated as faulted, position lost.
    - :meth:`events_waiting` says, without taking anything, whether :meth:`events` has
      something: the dispatcher looks before each command instead of asking for events
      that are almost never there.
    """

    def __init__(self, motors: int) -> None:
        self.motors = motors
        self.on_event: Callable[[], None] = lambda: None

    # -- lifecycle ---------------------------------------------------------------
    def start(self) -> None:  # noqa: B027  (optional hook: an executor may need nothing)
        """Start running (threads, processes, devices); returns once it is ready."""

    def close(self) -> None:  # noqa: B027
        """Stop every motor at once and release everything; idempotent."""

    # -- commands (engine lock held) ----------------------------------------------
    @abstractmethod
    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        """Start ``traj``; False when it makes no step at all (then nothing is reported)."""

    @abstractmethod
    def stop(self, motor: int, gen: int) -> int | None: ...

    @abstractmethod
    def committed(self, motor: int, now: float) -> Committed: ...

    @abstractmethod
    def service(self, now: float) -> float: ...

    @abstractmethod
    def events(self) -> list[ExecEvent]: ...

    @abstractmethod
    def events_waiting(self) -> bool:
        """A cheap look, by the events' consumer (the engine lock held): False only when
        :meth:`events` would return nothing now. What the executor reports is published
        with one atomic store (a deque's or a list's append, a ring's head cell), and this
        look reads that same store: an event published before it is seen by it, one
        published after it by the next look (the caller's next command, the planner's next
        pass). True when in doubt: :meth:`events` is then asked, as it always was."""

    @abstractmethod
    def planned(self, motor: int) -> bool:
        """True while anything of the motor's current plan remains to be executed."""

    # -- snapshots (any thread, no lock) ------------------------------------------
    @abstractmethod
    def position(self, motor: int) -> int: ...

    @abstractmethod
    def endstop_active(self, motor: int, direction: int) -> bool:
        """The end stop's current level (direction +1: max, -1: min); False if not wired."""

    @abstractmethod
    def health(self) -> ExecutorHealth: ...

    def motor_time(self, motor: int, now: float) -> float:
        """The motor's own time at clock time ``now``, on which its plans run: behind the
        clock by what its schedule has slid (late steps; docs/timing.md), else ``now``."""
        return now

    def motor_timing(self, motor: int) -> dict[str, Any]:
        """The motor's late-step figures (``motorctld --status``; docs/timing.md): steps
        absorbed by sliding its schedule, the worst lateness and lag, lag faults. Empty for
        an executor that times no steps of that motor."""
        return {}

    @property
    def times_steps(self) -> bool:
        """True when this executor times STEP edges (a step executor, or a split with one);
        False for one whose every motor its driver chip moves on its own ramp. What readers
        outside motion (the status) ask instead of the executor's class."""
        return True

    def step_lateness(self) -> LatencyStats | None:
        """The lateness histogram of the STEP edges this executor makes (read without a lock);
        None for an executor that makes none (a chip running its own ramp)."""
        return None

    def step_core(self) -> str | None:
        """Which step core times this executor's STEP edges: "compiled" or "python"
        (``[step_thread] core``); None for an executor that makes none, or before it runs."""
        return None

    def realtime(self) -> RealtimeReport | None:
        """What real time the thread or process that times the STEP edges asked for and got
        (motion/rt.py); None for an executor that makes none, or before it runs."""
        return None

    # -- a virtual clock (tests): executors that run on their own refuse ----------------
    def next_deadline(self) -> float | None:
        """The next time the executor needs the caller's thread (virtual clock only)."""
        raise TypeError(f"{type(self).__name__} does not run on a virtual clock")

    def advance(self, now: float) -> None:
        """Do everything due at ``now`` (virtual clock only)."""
        raise TypeError(f"{type(self).__name__} does not run on a virtual clock")
