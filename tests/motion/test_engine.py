"""The motion engine (motion/engine.py) on the mock world under a virtual clock: a move's
timeline is the planned one, motors step independently, positions are readable while they
move, the shutdown soft-stops everything, the DC motor's runs, the engine's own checks and
deadlines, and random command mixes over several motors keep every invariant. (One motor's
state machine: test_motor.py.)"""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.backends.mock.world import EventKind, mock_axis
from motorctl.hal.interfaces import BridgeState, MonotonicClock, VirtualClock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.engine import ChangeLock, MotionEngine
from motorctl.motion.executors.base import ExecEvent
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.types import MotorState, MoveToCmd, Ramp, RunCmd
from tests.support.motor_defaults import motor_params
from tests.support.rigs import engine_rig, planned_times

FAST = settings(max_examples=40, deadline=None)
RAMP = Ramp(2000.0, 8000.0, 8000.0)
POLL = 0.01


# ---------------------------------------------------------------- step-time helpers


def trapezoid_times(distance: int, vmax: float, acc: float, dec: float) -> list[float]:
    """Closed-form step times (from 0) of a move from rest to rest over ``distance`` steps."""
    n_total = abs(distance)
    d = float(n_total)
    if vmax * vmax / (2 * acc) + vmax * vmax / (2 * dec) <= d:
        vp = vmax
    else:
        vp = math.sqrt(2 * d * acc * dec / (acc + dec))
    da, dd = vp * vp / (2 * acc), vp * vp / (2 * dec)
    ta, td = vp / acc, vp / dec
    tc = (d - da - dd) / vp
    total = ta + tc + td
    out = []
    for n in range(1, n_total + 1):
        if n <= da:
            out.append(math.sqrt(2 * n / acc))
        elif n <= d - dd:
            out.append(ta + (n - da) / vp)
        else:
            out.append(total - math.sqrt(max(2 * (d - n) / dec, 0.0)))
    return out


# ---------------------------------------------------------------- single moves


@pytest.mark.parametrize(
    ("target", "ramp"),
    [
        (200, Ramp(2000.0, 8000.0, 8000.0)),  # triangular
        (900, Ramp(2000.0, 8000.0, 8000.0)),  # trapezoid
        (-700, Ramp(1500.0, 6000.0, 20000.0)),  # downwards, asymmetric ramps
        (1, Ramp(100.0, 1000.0, 1000.0)),
    ],
)
def test_move_timeline_is_the_planned_one(target: int, ramp: Ramp) -> None:
    rig = engine_rig()
    t0 = rig.clock.now()
    rig.submit(MoveToCmd(target, ramp))
    assert rig.state() is MotorState.MOVING
    rig.engine.run_until_idle()

    times = rig.times()
    assert times == planned_times(t0, 0, target, ramp)
    closed = [t0 + t for t in trapezoid_times(target, ramp.speed, ramp.acc, ramp.dec)]
    assert times == pytest.approx(closed, abs=1e-9)
    assert set(rig.dirs()) == {target > 0}
    assert rig.m.position == target == rig.axis()
    assert rig.state() is MotorState.IDLE and rig.m.idle
    assert rig.event_times("start") == [t0]
    assert rig.event_times("idle") == [times[-1]]
    # DIR was set once, a setup time before the first step; no step was late.
    dir_events = rig.world.timeline.of(EventKind.DIR, 0)
    assert len(dir_events) == 1 and dir_events[0].value == (target > 0)
    assert times[0] - dir_events[0].t >= rig.m.params.dir_setup_s
    assert rig.executor.stats.count == abs(target)
    assert rig.executor.stats.max_s == 0.0


def test_invert_dir_swaps_the_dir_line_not_the_motion() -> None:
    rig = engine_rig(axes=[AxisSpec(invert_dir=True)])
    rig.submit(MoveToCmd(30, RAMP))
    rig.engine.run_until_idle()
    assert [e.value for e in rig.world.timeline.of(EventKind.DIR, 0)] == [False]
    assert rig.m.position == 30 == rig.axis()


def test_two_motors_step_independently() -> None:
    rig = engine_rig(motor_params(name="a"), motor_params(name="b"))
    t0 = rig.clock.now()
    rig.submit(MoveToCmd(300, RAMP), 0)
    rig.submit(MoveToCmd(-150, Ramp(900.0, 3000.0, 3000.0)), 1)
    rig.engine.run_until_idle()
    assert rig.times(0) == planned_times(t0, 0, 300, RAMP)
    assert rig.times(1) == planned_times(t0, 0, -150, Ramp(900.0, 3000.0, 3000.0))
    assert (rig.motor(0).position, rig.motor(1).position) == (300, -150)
    assert (rig.axis(0), rig.axis(1)) == (300, -150)


def test_position_readable_while_moving() -> None:
    rig = engine_rig()
    rig.submit(MoveToCmd(900, RAMP))
    seen = []
    for _ in range(100):
        if rig.m.idle:
            break
        rig.advance(0.05)
        seen.append(rig.m.position)
        assert rig.m.position == rig.axis()
    assert seen == sorted(seen) and 0 < seen[0] < 900 and seen[-1] == 900 and rig.m.idle


def test_engine_shutdown_soft_stops_everything() -> None:
    rig = engine_rig(motor_params(), motor_params(), dc=True)
    rig.submit(RunCmd(1, RAMP), 0)
    rig.submit(MoveToCmd(-5000, RAMP), 1)
    with rig.engine.lock:
        rig.engine.dc_run(True, 10.0, BridgeState.COAST)
    rig.advance(0.5)
    rig.engine.shutdown()
    assert rig.engine.dc is not None and not rig.engine.dc.running
    assert rig.world.bridge is not None and rig.world.bridge.state is BridgeState.BRAKE
    rig.engine.run_until_idle(limit_s=1.0)
    assert not rig.engine.any_active
    assert [m.position for m in rig.engine.motors] == [rig.axis(0), rig.axis(1)]


# ---------------------------------------------------------------- DC motor


@pytest.mark.parametrize("end", [BridgeState.BRAKE, BridgeState.COAST])
def test_dc_run_ends_at_exactly_now_plus_duration(end: BridgeState) -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(False, 0.25, end)
    assert rig.engine.any_active
    rig.engine.run_until_idle()
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "reverse"), (t0 + 0.25, end.value)]
    assert rig.world.bridge is not None and rig.world.bridge.state is end


def test_dc_new_run_replaces_the_old_one() -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(True, 1.0, BridgeState.COAST)
    t1 = rig.advance(0.3)
    with rig.engine.lock:
        rig.engine.dc_run(True, 0.5, BridgeState.BRAKE)
    t2 = rig.advance(0.25)
    with rig.engine.lock:
        rig.engine.dc_run(False, 0.5, BridgeState.COAST)
    rig.advance(2.0)
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "forward"), (t2, "reverse"), (t2 + 0.5, "coast")]
    assert t1 + 0.5 > t2  # the second run never got to brake


def test_dc_duration_zero_stops_at_once() -> None:
    rig = engine_rig(dc=True)
    t0 = rig.clock.now()
    with rig.engine.lock:
        rig.engine.dc_run(True, 1.0, BridgeState.COAST)
    t1 = rig.advance(0.1)
    with rig.engine.lock:
        rig.engine.dc_run(True, 0.0, BridgeState.BRAKE)
    assert rig.engine.dc is not None and not rig.engine.dc.running
    rig.advance(2.0)
    dc = [(e.t, e.value) for e in rig.world.timeline.of(EventKind.DC)]
    assert dc == [(t0, "forward"), (t1, "brake")]


def test_dc_run_rejects_a_driving_end_state_and_missing_motor() -> None:
    rig = engine_rig(dc=True)
    with rig.engine.lock, pytest.raises(ValueError):
        rig.engine.dc_run(True, 1.0, BridgeState.FORWARD)
    with engine_rig().engine.lock, pytest.raises(LookupError):
        engine_rig().engine.dc_run(True, 1.0, BridgeState.BRAKE)


# ---------------------------------------------------------------- engine plumbing


def test_engine_checks_its_configuration_and_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(AxisSpec(),))
    hw = build(spec, clock)
    one = ThreadStepExecutor(hw, "mock", spec, axis_limits([motor_params()], 0.0))
    with pytest.raises(ValueError, match="2 motors configured"):
        MotionEngine(hw, [motor_params(), motor_params()], one)
    with pytest.raises(ValueError, match="real clock"):
        MotionEngine(hw, [motor_params()], one).start()
    real = build(spec, MonotonicClock())
    ex = ThreadStepExecutor(real, "mock", spec, axis_limits([motor_params()], 0.0))
    engine = MotionEngine(real, [motor_params()], ex)
    with pytest.raises(TypeError):
        engine.run_until(1.0)
    with pytest.raises(TypeError):
        engine.run_until_idle()
    with pytest.raises(TypeError, match="virtual clock"):
        ex.advance(1.0)


def test_run_until_idle_gives_up_on_an_endless_run() -> None:
    rig = engine_rig(axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)])
    rig.submit(RunCmd(1, Ramp(10.0, 100.0, 100.0)))
    with pytest.raises(TimeoutError):
        rig.engine.run_until_idle(limit_s=1.0)


def test_deadlines() -> None:
    rig = engine_rig(dc=True)
    e = rig.engine
    assert rig.executor.next_deadline() is None
    assert e.next_deadline() == rig.clock.now()  # the driver poller's first reads: at once
    e.run_until(rig.clock.now())
    assert e.next_deadline() == rig.clock.now() + POLL  # then every period
    with e.lock:
        e.dc_run(True, 0.001, BridgeState.BRAKE)
        e.service(rig.clock.now())
    assert e.next_deadline() == rig.clock.now() + 0.001
    rig.submit(MoveToCmd(10, RAMP))
    with e.lock:
        e.service(rig.clock.now())
    first = planned_times(rig.clock.now(), 0, 10, RAMP)[0]
    assert e.next_deadline() == rig.clock.now() + 0.001 < first
    rig.advance(0.002)
    assert rig.executor.next_deadline() == first  # handed to the step core
    assert e.next_deadline() == min(first, rig.clock.now() - 0.002 + POLL)


def test_a_driver_fault_is_acted_on_as_soon_as_the_poller_pushes_it() -> None:
    """What the driver poller read is not left for a tick of the engine's own: the planner
    is woken, and whoever processes the engine's events next (the dispatcher, before it
    answers a command) acts on it, under the lock."""
    rig = engine_rig()
    e, m = rig.engine, rig.m
    e.run_until(rig.clock.now())
    rig.world.inject_fault(0, "over-temperature")
    e.wake.clear()
    e.poller.poll_due(e.poller.next_due())  # the poller's thread reads the drivers
    assert e.wake.is_set()
    assert m.fault is None  # queued: the engine acts on its own thread, under its lock
    with e.lock:
        e.process_events(rig.clock.now())
    assert m.state is MotorState.FAULT and m.fault == "driver fault: over-temperature"
    assert e.hardware_errors == 0  # a fault the chip reports is no failed call


# ---------------------------------------------------------------- properties


RAMPS = [
    Ramp(3000.0, 30000.0, 30000.0),
    Ramp(800.0, 4000.0, 1500.0),
    Ramp(5000.0, 8000.0, 100000.0),
    Ramp(2000.0, 100000.0, 3000.0),
]
actions = st.lists(
    st.one_of(
        st.tuples(
            st.just("move"), st.integers(min_value=-1000, max_value=1000), st.sampled_from(RAMPS)
        ),
        st.tuples(st.just("run"), st.sampled_from([1, -1]), st.sampled_from(RAMPS)),
        st.tuples(st.just("stop"), st.booleans(), st.just(RAMPS[0])),
    ),
    min_size=1,
    max_size=8,
)


@FAST
@given(actions, st.lists(st.floats(min_value=0.0, max_value=0.4), min_size=8, max_size=8))
def test_random_command_mixes_keep_every_invariant(
    script: list[tuple[str, int | bool, Ramp]], waits: list[float]
) -> None:
    rig = engine_rig(
        motor_params(soft_min=-1000, soft_max=1000),
        axes=[mock_axis(endstop_min=-100_000, endstop_max=100_000)],
    )
    for (kind, arg, ramp), dt in zip(script, waits, strict=False):
        if kind == "stop":
            assert rig.stop(hard=bool(arg))
            if arg:
                assert rig.m.idle and rig.m.traj is None and not rig.executor.planned(0)
            assert not rig.m.queue
        elif not rig.m.queue_full:
            if kind == "move":
                assert rig.m.target_allowed(int(arg))
                rig.submit(MoveToCmd(int(arg), ramp))
            else:
                rig.submit(RunCmd(int(arg), ramp))
        rig.advance(dt)
        assert rig.m.position == rig.axis()
        assert rig.m.fault is None
    assert rig.stop(hard=False)
    rig.engine.run_until_idle()
    assert rig.m.idle and rig.m.position == rig.axis()
    p = lo = hi = 0
    for d in rig.dirs():
        p += 1 if d else -1
        lo, hi = min(lo, p), max(hi, p)
    assert lo >= -1000 and hi <= 1000
    times = rig.times()
    assert all(b > a for a, b in itertools.pairwise(times))


def test_a_fault_on_one_motor_leaves_the_other_alone() -> None:
    rig = engine_rig(motor_params(), motor_params())
    rig.submit(MoveToCmd(800, RAMP), 0)
    rig.submit(MoveToCmd(-800, RAMP), 1)
    rig.advance(0.1)
    rig.world.inject_fault(0, "short")
    rig.engine.run_until_idle()
    assert rig.motor(0).fault == "driver fault: short" and rig.motor(1).fault is None
    assert rig.motor(1).position == -800 == rig.axis(1)
    assert rig.motor(0).position == rig.axis(0) < 800


def test_the_motion_lock_counts_its_releases_once_the_holder_is_done() -> None:
    """``releases`` moves on as the lock is let go (each nested level too), never while it
    is held: the status server's sign that a change is whole (daemon/status/document.py)."""
    lock = ChangeLock()
    assert lock.releases == 0
    with lock:
        with lock:  # re-entrant
            assert lock.releases == 0
        assert lock.releases == 1
    assert lock.releases == 2
    assert lock._lock.acquire(blocking=False)  # let go: free again
    lock._lock.release()


def test_the_executors_look_says_whether_events_wait_at_every_request_for_them() -> None:
    """``events_waiting`` (what the dispatcher's ``catch_up`` looks at before each command)
    is True exactly when ``events`` has something, at every request for them during a
    move's DONE, a hard stop's STOPPED, an end stop's ENDSTOP (a fault: not homing) and the
    quiet between."""
    rig = engine_rig()
    ex = rig.executor
    looks: list[tuple[bool, int]] = []
    take = ex.events

    def events() -> list[ExecEvent]:
        waiting = ex.events_waiting()
        out = take()
        looks.append((waiting, len(out)))
        return out

    ex.events = events  # type: ignore[method-assign]
    ramp = Ramp(4000.0, 40_000.0, 40_000.0)
    rig.submit(MoveToCmd(300, ramp))
    rig.engine.run_until_idle()
    rig.submit(RunCmd(1, ramp))
    rig.advance(0.05)
    assert rig.stop(hard=True)
    rig.engine.run_until_idle()
    rig.submit(RunCmd(-1, ramp))  # into the end stop at -1000
    rig.engine.run_until_idle()
    assert [e for _, _, e in rig.events][-1] == "fault", rig.events  # the end stop's
    assert all(waiting == bool(n) for waiting, n in looks), looks
    assert sum(1 for waiting, _ in looks if waiting) >= 3 and (False, 0) in looks
