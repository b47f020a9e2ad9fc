"""The ``thread`` step executor and the engine's threads on the real monotonic clock.

Every wait is on an event set by an engine listener (or a bounded wait for a condition) with a
generous timeout; the assertions are about positions and step counts, never about timing.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from motorctl.hal.interfaces import BridgeState, MonotonicClock, VirtualClock
from motorctl.hal.mock import EventKind, MockWorld, build, world_of
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.motor import Motor
from motorctl.motion.rt import GcPolicy
from motorctl.motion.stepexec import ThreadStepExecutor, axis_limits
from motorctl.motion.types import (
    HomeCmd,
    MotionCmd,
    MotorParams,
    MotorState,
    MoveToCmd,
    Ramp,
    RunCmd,
)

TIMEOUT = 20.0
FAST = Ramp(4000.0, 40000.0, 40000.0)


@dataclass
class Live:
    engine: MotionEngine
    world: MockWorld
    thread: ThreadStepExecutor
    events: dict[str, threading.Event]

    @property
    def m(self) -> Motor:
        return self.engine.motors[0]

    def submit(self, cmd: MotionCmd) -> None:
        with self.engine.lock:
            self.m.submit(cmd, self.engine.clock.now())
        self.engine.wake.set()

    def stop(self, hard: bool) -> bool:
        with self.engine.lock:
            ok = self.m.stop(hard, self.engine.clock.now())
        self.engine.wake.set()
        return ok

    def wait(self, name: str) -> None:
        assert self.events[name].wait(TIMEOUT), (
            f"no {name!r} within {TIMEOUT} s (fault: {self.m.fault})"
        )
        self.events[name].clear()

    def wait_steps(self, n: int) -> None:
        """Block until at least ``n`` steps happened (bounded by TIMEOUT)."""
        done = threading.Event()
        for _ in range(int(TIMEOUT / 0.002)):
            with self.engine.lock:
                if len(self.world.timeline.of(EventKind.STEP, 0)) >= n:
                    return
            done.wait(0.002)
        raise AssertionError(f"fewer than {n} steps within {TIMEOUT} s")

    def settled(self) -> tuple[int, int, int]:
        """Motor position, mock axis position and the number of recorded steps."""
        with self.engine.lock:
            steps = self.world.timeline.counts[EventKind.STEP]
            return self.m.position, self.world.axes[0].position, steps


@pytest.fixture
def live(request: pytest.FixtureRequest) -> Iterator[Live]:
    params: MotorParams = getattr(request, "param", MotorParams())
    clock = MonotonicClock()
    spec = HardwareSpec(
        axes=(AxisSpec(endstop_min=-5000, endstop_max=5000),),
        dc=True,
        options={"timeline_len": None},
    )
    hw = build(spec, clock)
    # the mock's own rule (simulated motors: late steps slide), as the embedded default's
    limits = axis_limits([params], 5e-6, lag_faults=hw.motors_lose_steps)
    executor = ThreadStepExecutor(hw, "mock", spec, limits)
    engine = MotionEngine(hw, [params], executor, driver_poll_s=0.005)
    names = ("start", "idle", "fault", "homed", "cleared")
    events = {name: threading.Event() for name in names}

    def listener(motor: Motor, event: str) -> None:
        events[event].set()

    engine.listeners.append(listener)
    executor.start()
    engine.start()
    try:
        yield Live(engine, world_of(hw), executor, events)
    finally:
        engine.stop_threads()
        executor.close()
        assert not executor.health().alive
        assert executor.health().reason is None  # closed, not died


def test_refuses_a_virtual_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(AxisSpec(),))
    hw = build(spec, clock)
    ex = ThreadStepExecutor(hw, "mock", spec, axis_limits([MotorParams()], 0.0))
    with pytest.raises(ValueError, match="real clock"):
        MotionEngine(hw, [MotorParams()], ex).start()


def test_a_short_move_completes(live: Live) -> None:
    assert live.thread.warnings == []
    live.submit(MoveToCmd(400, FAST))
    live.wait("idle")
    assert live.settled() == (400, 400, 400)
    assert {e.value for e in live.world.timeline.of(EventKind.STEP, 0)} == {True}
    assert live.m.state is MotorState.IDLE and live.m.idle
    assert live.thread.stats.count == 400
    assert live.thread.health().counters["steps"] == 400


def test_queued_moves_run_in_order(live: Live) -> None:
    live.submit(MoveToCmd(300, FAST))
    live.submit(MoveToCmd(-200, FAST))
    live.submit(MoveToCmd(50, FAST))
    live.wait("idle")
    values = [e.value for e in live.world.timeline.of(EventKind.STEP, 0)]
    assert values == [True] * 300 + [False] * 500 + [True] * 250
    assert live.settled() == (50, 50, 1050)


def test_homing_on_the_real_clock(live: Live) -> None:
    live.submit(MoveToCmd(-4000, Ramp(20000.0, 200000.0, 200000.0)))
    live.submit(HomeCmd(-1, FAST))
    live.wait("idle")
    assert live.events["homed"].is_set()
    pos, axis, _ = live.settled()
    assert (pos, axis) == (0, -5000)


@pytest.mark.parametrize("live", [MotorParams(soft_min=-100, soft_max=350)], indirect=True)
def test_a_run_ends_at_the_soft_limit(live: Live) -> None:
    live.submit(RunCmd(1, FAST))
    live.wait("idle")
    assert live.settled() == (350, 350, 350)


@pytest.mark.parametrize("hard", [True, False])
def test_stop_from_another_thread(live: Live, hard: bool) -> None:
    live.submit(RunCmd(-1, Ramp(2000.0, 20000.0, 20000.0)))
    live.wait("start")
    live.wait_steps(100)
    assert live.stop(hard=hard)
    live.wait("idle")
    pos, axis, steps = live.settled()
    assert pos == axis == -steps and steps >= 100
    assert live.m.idle


def test_driver_fault_on_the_real_clock(live: Live) -> None:
    live.submit(RunCmd(1, Ramp(2000.0, 20000.0, 20000.0)))
    live.wait_steps(20)
    live.world.inject_fault(0, "over-temperature")
    live.wait("fault")
    assert live.m.fault == "driver fault: over-temperature"
    assert not live.stop(hard=False)
    live.world.inject_fault(0, None)
    assert live.stop(hard=False)
    live.wait("cleared")
    pos, axis, steps = live.settled()
    assert pos == axis == steps


def test_dc_run_on_the_real_clock(live: Live) -> None:
    bridge = live.world.bridge
    assert bridge is not None
    with live.engine.lock:
        live.engine.dc_run(True, 0.05, BridgeState.COAST)
    live.engine.wake.set()
    done = threading.Event()
    for _ in range(int(TIMEOUT / 0.005)):
        with live.engine.lock:
            if not live.engine.any_active:
                break
        done.wait(0.005)
    assert bridge.state is BridgeState.COAST
    assert [e.value for e in live.world.timeline.of(EventKind.DC)] == ["forward", "coast"]


def test_gc_policy_switches_automatic_collection() -> None:
    was = gc.isenabled()
    policy = GcPolicy()
    try:
        policy.motion(True)
        assert not gc.isenabled()
        policy.motion(False)
        assert gc.isenabled()
    finally:
        if was:
            gc.enable()
        else:
            gc.disable()
