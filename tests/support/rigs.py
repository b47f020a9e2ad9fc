"""Rigs on a virtual clock: the step core fed by hand (``StepCoreRig``), and the motion
engine over the mock world with the thread step executor, on a
virtual clock (time passes only when the test says: ``advance``), or on the real clock with
the engine's and the executor's threads running (``start``; waits on the engine's events
with a deadline).
"""

from __future__ import annotations

import threading
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from motorctl.hal.backends.mock.backend import build, build_step_io
from motorctl.hal.backends.mock.world import Event, EventKind, MockWorld, mock_axis, world_of
from motorctl.hal.interfaces import Clock, Hardware, StepperDriver, VirtualClock
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ExecEvent, Executor, from_ticks, to_ticks
from motorctl.motion.executors.compiled_core import CompiledStepCore
from motorctl.motion.executors.core_cells import COUNTER_NAMES, MOTOR_CELLS
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.process.child import RingInbox
from motorctl.motion.executors.process.rings import Layout, Shared, segment_fields
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.executors.step_core import StepCore
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.latency import LatencyStats
from motorctl.motion.motor import Motor
from motorctl.motion.profile import Steps, plan_move_to
from motorctl.motion.types import MotionCmd, MotorParams, MotorState, Ramp
from tests.support.motor_defaults import motor_params
from tests.support.wait import WAIT_S


def planned_times(t0: float, start: int, target: int, r: Ramp) -> list[float]:
    """The step times of a MoveTo from rest at ``t0``, planned by the profile, on the step
    path's 1 ns ticks."""
    traj = plan_move_to(t0, float(start), 0.0, float(target), r.speed, r.acc, r.dec)
    return [from_ticks(to_ticks(t)) for t, _ in Steps(traj, start)]


#: End stops no test reaches.
FAR = mock_axis(endstop_min=-(10**9), endstop_max=10**9)

#: Builds a rig's executor from its hardware, spec and motors (default: the thread one).
ExecutorFactory = Callable[[Hardware, HardwareSpec, list[MotorParams]], Executor]


@dataclass
class EngineRig:
    clock: Clock
    hw: Hardware
    world: MockWorld
    engine: MotionEngine
    #: (time, motor, event) of every engine event, in order
    events: list[tuple[float, int, str]] = field(default_factory=list)
    #: set at each engine event of that name (``wait`` clears it)
    signals: defaultdict[str, threading.Event] = field(
        default_factory=lambda: defaultdict(threading.Event)
    )

    def state(self, i: int = 0) -> MotorState:
        """The motor's state, read afresh (a call, so type checkers do not pin it)."""
        return self.engine.motors[i].state

    @property
    def executor(self) -> ThreadStepExecutor:
        ex = self.engine.executor
        assert isinstance(ex, ThreadStepExecutor)
        return ex

    def motor(self, i: int = 0) -> Motor:
        return self.engine.motors[i]

    @property
    def m(self) -> Motor:
        return self.engine.motors[0]

    def submit(self, cmd: MotionCmd, i: int = 0) -> None:
        with self.engine.lock:
            self.engine.motors[i].submit(cmd, self.clock.now())
        self.engine.wake.set()

    def stop(self, hard: bool, i: int = 0) -> bool:
        with self.engine.lock:
            ok = self.engine.motors[i].stop(hard, self.clock.now())
        self.engine.wake.set()
        return ok

    def steps(self, i: int = 0) -> list[Event]:
        return self.world.timeline.of(EventKind.STEP, i)

    def times(self, i: int = 0) -> list[float]:
        return self.world.timeline.step_times(i)

    def dirs(self, i: int = 0) -> list[bool]:
        return [bool(e.value) for e in self.steps(i)]

    def axis(self, i: int = 0) -> int:
        return self.world.axes[i].position

    def advance(self, dt: float) -> float:
        """Virtual clock: run the engine ``dt`` seconds on; the time it reached."""
        t = self.clock.now() + dt
        self.engine.run_until(t)
        return t

    def event_times(self, name: str, i: int = 0) -> list[float]:
        return [t for t, idx, e in self.events if e == name and idx == i]

    # ------------------------------------------------------------ on the real clock

    def start(self) -> None:
        """Start the executor's and the engine's threads (a real clock)."""
        self.engine.executor.start()
        self.engine.start()

    def close(self) -> None:
        self.engine.stop_threads()
        self.engine.executor.close()
        assert not self.engine.executor.health().alive

    def wait(self, name: str, timeout: float = WAIT_S) -> None:
        """Until the engine's next ``name`` event (one since the last wait counts)."""
        assert self.signals[name].wait(timeout), (
            f"no {name!r} within {timeout} s (fault: {self.m.fault})"
        )
        self.signals[name].clear()

    def wait_steps(self, n: int, timeout: float = WAIT_S) -> None:
        """Until motor 0 made at least ``n`` steps."""
        pause = threading.Event()
        for _ in range(int(timeout / 0.002)):
            with self.engine.lock:
                if len(self.world.timeline.of(EventKind.STEP, 0)) >= n:
                    return
            pause.wait(0.002)
        raise AssertionError(f"fewer than {n} steps within {timeout} s")

    def settled(self) -> tuple[int, int, int]:
        """Motor 0's position, its mock axis' position and the number of recorded steps."""
        with self.engine.lock:
            steps = self.world.timeline.counts[EventKind.STEP]
            return self.m.position, self.world.axes[0].position, steps


def engine_rig(
    *params: MotorParams,
    axes: Sequence[AxisSpec] | None = None,
    dc: bool = False,
    lows: Sequence[bool] | None = None,
    clock: Clock | None = None,
    max_error_s: float = 0.0,
    lag_faults: bool | None = True,
    ahead_s: float | None = None,
    lead_s: float | None = None,
    driver_poll_s: float = 0.01,
    drivers: Sequence[StepperDriver] = (),
    executor: ExecutorFactory | None = None,
) -> EngineRig:
    """One motor per ``params`` (one default motor without) over the mock world.

    ``axes``: the mock's axes (default: end stops at -1000 and 1000); ``lows``: their end
    stops active low or not; ``clock``: a virtual clock unless given; ``max_error_s``,
    ``lag_faults`` (None: the mock's own rule, simulated motors slide), ``ahead_s`` and
    ``lead_s``: the thread step executor's; ``driver_poll_s``: the driver poller's period;
    ``drivers``: the first motors' drivers instead of the mock's (the poller reads them, as
    a layer registers its chips); ``executor``: another executor instead.
    """
    if not params:
        params = (motor_params(),)
    if axes is None:
        axes = [mock_axis(endstop_min=-1000, endstop_max=1000) for _ in params]
    if lows is not None:
        axes = [replace(a, endstop_active_low=low) for a, low in zip(axes, lows, strict=True)]
    clock = clock or VirtualClock()
    spec = HardwareSpec(axes=tuple(axes), dc=dc, options={"timeline_len": None})
    hw = build(spec, clock)
    hw.poller.period_s = driver_poll_s
    for i, (stepper, driver) in enumerate(zip(hw.steppers, drivers, strict=False)):
        hw.poller.forget(stepper.driver)
        stepper.driver = driver
        hw.poller.watch(driver, f"motor {i}'s driver")
    if executor is not None:
        ex = executor(hw, spec, list(params))
    else:
        faults = hw.motors_lose_steps if lag_faults is None else lag_faults
        limits = axis_limits(params, max_error_s, lag_faults=faults)
        ex = ThreadStepExecutor(hw, "mock", spec, limits, ahead_s=ahead_s, lead_s=lead_s)
    engine = MotionEngine(hw, list(params), ex)
    rig = EngineRig(clock, hw, world_of(hw), engine)

    def record(m: Motor, e: str) -> None:
        rig.events.append((clock.now(), m.index, e))
        rig.signals[e].set()

    engine.listeners.append(record)
    return rig


class StepCoreRig:
    """A step core on a virtual clock over the mock world, fed by hand through the process
    executor's shared-memory rings (the same records, checked the same way, for both
    cores): ``core`` "python" (motion/executors/step_core.py over ``RingInbox``) or
    "compiled" (motion/executors/compiled_core.py). Lateness is judged by the real-hardware rule
    (``lag_faults``) unless a test says otherwise. ``close()`` releases the block."""

    def __init__(
        self,
        motors: int = 1,
        max_speed: float = 10_000.0,
        *,
        core: str = "python",
        start_speed: float = 0.0,
        microsteps: int = 16,
        max_lag: float = 0.5,
        lag_faults: bool = True,
        coalesce_s: float = 0.0,
        axes: Sequence[AxisSpec] | None = None,
        dir_setup_s: float | None = None,
        dir_hold_s: float | None = None,
        late_threshold_s: float = 100e-6,
        debounce_s: float = 0.0,
    ) -> None:
        self.kind = core
        self.clock = VirtualClock()
        if axes is None:
            axes = (FAR,) * motors
        if dir_setup_s is not None:
            axes = [replace(a, dir_setup_s=dir_setup_s) for a in axes]
        if dir_hold_s is not None:
            axes = [replace(a, dir_hold_s=dir_hold_s) for a in axes]
        spec = HardwareSpec(axes=tuple(axes), options={"timeline_len": None})
        self.hw = build(spec, self.clock)
        self.world = world_of(self.hw)
        io = build_step_io(spec, self.clock, self.hw)
        params = motor_params(
            max_speed=max_speed,
            start_speed=start_speed,
            microsteps=microsteps,
            max_lag_full_steps=max_lag,
            debounce_s=debounce_s,
        )
        self.limits = axis_limits([params] * motors, 0.0, lag_faults=lag_faults)
        self.layout = Layout(motors, len(io.inputs.names))
        self.shm = SharedBlock.create(self.layout.size, "motorctl-test-core")
        self.shared = Shared(self.shm, self.layout)
        self.events: list[ExecEvent] = []
        self.positions = self.shared.positions
        self.cells = self.shared.motor_cells
        self.core: StepCore | CompiledStepCore
        if core == "python":
            self.inbox = RingInbox(self.shared, self.clock)
            self.core = StepCore(
                io,
                self.limits,
                self.inbox,
                self.events.append,
                positions=self.shared.positions,
                levels=self.shared.levels,
                counters=self.shared.counters,
                stats=LatencyStats(late_threshold_s, self.shared.latency),
                motor_cells=self.cells,
                coalesce_s=coalesce_s,
            )
        elif core == "compiled":
            self.core = CompiledStepCore(
                io,
                self.limits,
                self.shared,
                late_threshold_s=late_threshold_s,
                coalesce_s=coalesce_s,
                emit=self.events.append,
            )
        else:
            raise ValueError(f"no step core {core!r}")
        self._closed = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if isinstance(self.core, CompiledStepCore):
            self.core.close()
        self.shared.release()
        self.shm.close()
        self.hw.close()

    def cell(self, which: int, motor: int = 0) -> int:
        return int(self.cells[motor * MOTOR_CELLS + which])

    def counter(self, name: str) -> int:
        return int(self.shared.counters[COUNTER_NAMES.index(name)])

    def push(self, motor: int, *segments: StepSegment) -> None:
        """Segments into the motor's ring, as the daemon's planner hands them over."""
        ring = self.shared.segs[motor]
        for seg in segments:
            assert ring.put(*segment_fields(seg)), "segment ring full"

    def stop(self, motor: int, gen: int, cut: int = -1) -> None:
        """A stop record (``cut`` -1: a hard stop; else a re-plan from that tick)."""
        assert self.shared.stops.put(motor, gen, cut), "stop ring full"

    def cruise(self, motor: int, rate: float, count: int, start: float, gen: int = 1) -> None:
        iv = to_ticks(1.0 / rate)
        self.push(motor, StepSegment(to_ticks(start), iv, count, 0, 1, gen))

    def run_until(self, t: float) -> None:
        core = self.core
        if isinstance(core, CompiledStepCore):
            core.run_until(to_ticks(t))
        else:
            core.refill()
            while (d := core.deadline()) is not None and d <= to_ticks(t):
                self.clock.advance_to(d / 1e9)  # never backwards: after a stall, "now" is later
                core.advance(to_ticks(self.clock.now()))
        self.clock.advance_to(t)

    def times(self, motor: int = 0) -> list[float]:
        return self.world.timeline.step_times(motor)

    def pulse_calls(self) -> list[list[int]]:
        """From now on, the motors of each STEP rise, one list per backend call."""
        if isinstance(self.core, CompiledStepCore):
            return self.core.pulse_calls()
        calls: list[list[int]] = []
        out = self.core.io.outputs
        real = out._write_steps

        def spy(motors: Sequence[int], level: bool) -> None:
            if level:
                calls.append(list(motors))
            real(motors, level)

        out._write_steps = spy  # type: ignore[method-assign]
        return calls
