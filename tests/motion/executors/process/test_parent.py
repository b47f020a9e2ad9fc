"""The ``process`` step executor (motion/executors/process/parent.py) on the real clock, on
each step core (Python, compiled): it moves and reports positions, its process dying faults
every motor, a stopped process never bursts afterwards (the real motors' rule) or slides a
simulated motor (the mock's), and it needs a real clock; which core it runs, and a clear
start error when the compiled one is asked for and cannot run; the start handshake (READY
after the child's byte, a child that exits before it, a start that times out) and the rings'
retries counted in its health. (The shared block's rings: test_rings.py; the child's own
checks: test_child.py.)"""

from __future__ import annotations

import itertools
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.backends.mock.world import EventKind, read_timeline, world_of
from motorctl.hal.interfaces import HalError, MonotonicClock, VirtualClock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import ExecEvent, ExecEventKind
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.process.parent import ProcessStepExecutor
from motorctl.motion.executors.process.rings import EVENT_KINDS, EVENT_RECORD, READY_CELL
from motorctl.motion.rt import RealtimeOptions
from motorctl.motion.types import MotorState, MoveToCmd, Ramp, RunCmd
from tests.support.executors import (
    REFUSE_SCHED_FIFO,
    interpreter_with,
    process_executor,
    show_slot,
    slot_bytes,
    slot_offset,
)
from tests.support.motor_defaults import motor_limits, motor_params
from tests.support.rigs import FAR
from tests.support.wait import until


@pytest.fixture
def proc(
    tmp_path: Path, request: pytest.FixtureRequest, step_core: str
) -> Iterator[tuple[MotionEngine, ProcessStepExecutor, Path]]:
    clock = MonotonicClock()
    timeline = tmp_path / "timeline.jsonl"
    spec = HardwareSpec(
        axes=(FAR, FAR),
        options={"timeline_len": None, "executor_process": True, "timeline_file": str(timeline)},
    )
    hw = build(spec, clock)
    params = [motor_params(max_speed=10_000.0)] * 2
    # tests run without real-time priority on a shared machine: the simulated motors' rule
    # (late steps slide, never a fault), but the real-hardware rule where the test is about it
    real = request.node.get_closest_marker("real_rule") is not None
    ex = ProcessStepExecutor(
        hw, "mock", spec, axis_limits(params, 5e-6, lag_faults=real), core=step_core
    )
    hw.poller.period_s = 0.01
    engine = MotionEngine(hw, params, ex)
    ex.start()
    assert ex.step_core() == step_core
    engine.start()
    try:
        yield engine, ex, timeline
    finally:
        engine.stop_threads()
        ex.close()
        hw.close()


def faults(engine: MotionEngine) -> Callable[[], object]:
    """What ``until`` names when it times out: each motor's fault."""
    return lambda: f"faults {[m.fault for m in engine.motors]}"


def test_the_process_executor_moves_and_reports_positions(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(
            MoveToCmd(400, Ramp(4000.0, 40_000.0, 40_000.0)), engine.clock.now()
        )
        engine.motors[1].submit(
            MoveToCmd(-250, Ramp(3000.0, 40_000.0, 40_000.0)), engine.clock.now()
        )
    until(
        "both motors idle",
        lambda: all(m.idle for m in engine.motors) and not any(ex.planned(i) for i in range(2)),
        detail=faults(engine),
    )
    assert [m.position for m in engine.motors] == [400, -250]
    world = world_of(engine.hw)
    assert [a.position for a in world.axes] == [400, -250]  # the shared mechanics
    assert ex.health().alive and ex.health().counters["steps"] == 650
    engine.stop_threads()
    ex.close()  # writes the child's timeline
    tl = read_timeline(str(timeline))
    assert len(tl.of(EventKind.STEP, 0)) == 400 and len(tl.of(EventKind.STEP, 1)) == 250


def test_the_executor_process_dying_faults_every_motor(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    engine, ex, _ = proc
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(2000.0, 20_000.0, 20_000.0)), engine.clock.now())
    until("steps", lambda: ex.position(0) > 50, detail=faults(engine))
    ex.kill_for_test(signal.SIGKILL)
    until("the faults", lambda: all(m.state is MotorState.FAULT for m in engine.motors))
    for m in engine.motors:
        assert m.position_lost and m.fault is not None and "died" in m.fault
    h = ex.health()
    assert not h.alive and h.reason is not None and "exit code -9" in h.reason
    assert engine.executor_died == h.reason


@pytest.mark.real_rule
def test_a_stopped_executor_does_not_burst_afterwards(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    """SIGSTOP for 50 ms while a motor runs at 5,000 step/s, then SIGCONT, with the real
    motors' rule: the motor stops with "step timing lost" (15 full steps of lag, tolerance
    0.5), and the smallest gap between two steps on the timeline is never below the profile's
    bound."""
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(RunCmd(1, Ramp(5000.0, 50_000.0, 50_000.0)), engine.clock.now())
    until(
        "cruise",
        lambda: ex.position(0) > 1000 or engine.motors[0].fault is not None,
        detail=faults(engine),
    )
    ex.kill_for_test(signal.SIGSTOP)
    time.sleep(0.05)
    ex.kill_for_test(signal.SIGCONT)
    until("the fault", lambda: engine.motors[0].state is MotorState.FAULT)
    m = engine.motors[0]
    assert m.fault is not None and m.fault.startswith("step timing lost")
    assert m.position_lost and ex.motor_timing(0)["lag_faults"] == 1
    engine.stop_threads()
    ex.close()
    times = read_timeline(str(timeline)).step_times(0)
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= ex.limits[0].min_interval_s - 1e-9
    assert len(times) == engine.motors[0].abs_steps


def test_a_stopped_executor_slides_a_simulated_motor(
    proc: tuple[MotionEngine, ProcessStepExecutor, Path],
) -> None:
    """The same stop on the mock's own rule: the move slides by the stop, reaches its target
    with every step, no fault, and the status figures of the executor process show it."""
    engine, ex, timeline = proc
    with engine.lock:
        engine.motors[0].submit(
            MoveToCmd(4000, Ramp(5000.0, 50_000.0, 50_000.0)), engine.clock.now()
        )
    until("cruise", lambda: ex.position(0) > 1000, detail=faults(engine))
    ex.kill_for_test(signal.SIGSTOP)
    time.sleep(0.05)
    ex.kill_for_test(signal.SIGCONT)
    until("the target", lambda: engine.motors[0].idle, detail=faults(engine))
    m = engine.motors[0]
    assert m.fault is None and m.position == 4000
    timing = ex.motor_timing(0)
    assert timing["late_absorbed"] >= 1 and timing["lag_faults"] == 0
    assert timing["worst_late_us"] >= 40_000 and timing["slid_ms"] >= 40
    engine.stop_threads()
    ex.close()
    assert ex.motor_timing(0) == timing  # kept after close
    times = read_timeline(str(timeline)).step_times(0)
    assert len(times) == 4000
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= ex.limits[0].min_interval_s - 1e-9
    assert max(gaps) >= 0.04  # the stop is in the timeline, not made up with a burst


def test_the_process_executor_needs_a_real_clock() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,))
    with pytest.raises(ValueError, match="real clock"):
        ProcessStepExecutor(build(spec, clock), "mock", spec, [motor_limits(1e-5)])


def test_auto_runs_the_compiled_core_where_it_is_built_and_the_backend_hands_lines_over(
    step_core: str,
) -> None:
    """The mock hands its lines over; "auto" takes the compiled core (built by make venv);
    "python" asked for is the Python core."""
    spec = HardwareSpec(axes=(FAR,), options={"executor_process": True})
    hw = build(spec, MonotonicClock())
    wanted = "auto" if step_core == "compiled" else "python"
    ex = ProcessStepExecutor(hw, "mock", spec, [motor_limits(1e-4)], core=wanted)
    try:
        ex.start()
        assert ex.step_core() == step_core and ex.health().alive
    finally:
        ex.close()
        hw.close()
    assert ex.step_core() == step_core  # kept after close (the status, the journal)


def test_the_compiled_core_asked_for_where_it_cannot_run_is_a_clear_start_error(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Not built (here: MOTORCTL_STEPCORE names no extension): "compiled" does not start,
    and says why; "auto" runs the Python core and says why not the compiled one."""
    monkeypatch.setenv("MOTORCTL_STEPCORE", str(tmp_path / "missing.so"))
    spec = HardwareSpec(axes=(FAR,), options={"executor_process": True})
    hw = build(spec, MonotonicClock())
    try:
        ex = ProcessStepExecutor(hw, "mock", spec, [motor_limits(1e-4)], core="compiled")
        try:
            with pytest.raises(HalError) as err:
                ex.start()
        finally:
            ex.close()
        text = str(err.value)
        assert text.startswith('the step executor cannot start: [step_thread] core = "compiled"')
        assert "the compiled step core is not built" in text and "missing.so" in text
        ex = ProcessStepExecutor(hw, "mock", spec, [motor_limits(1e-4)], core="auto")
        try:
            ex.start()
            assert ex.step_core() == "python" and "not the compiled core" in ex.core_note
        finally:
            ex.close()
    finally:
        hw.close()


# ---------------------------------------------------------------- the start handshake


def test_start_reads_ready_after_the_childs_byte_and_sees_its_end_stop_map() -> None:
    hw, ex = process_executor("mock")
    try:
        ex.start()
        # the child wrote the map before READY and its byte; -1/-1 or lines of its own
        lo, hi = ex.shared.endmap[0], ex.shared.endmap[1]
        assert ex.health().alive and ex.shared.header[READY_CELL] == 1
        assert (lo, hi) != (0, 0), "start returned before the child's end-stop map"
    finally:
        ex.close()
        hw.close()


def test_start_names_a_child_that_exits_before_it_is_ready() -> None:
    hw, ex = process_executor("no-such-backend")
    try:
        with pytest.raises(HalError, match="exited at start"):
            ex.start()
    finally:
        ex.close()
        hw.close()


def test_start_gives_up_after_its_timeout() -> None:
    hw, ex = process_executor("mock", start_timeout_s=0.001)
    try:
        with pytest.raises(HalError, match="did not start within"):
            ex.start()
        assert ex.proc is not None and ex.proc.poll() is not None
    finally:
        ex.close()
        hw.close()


def test_retries_of_both_directions_are_in_the_process_executors_health(step_core: str) -> None:
    """A torn record each way between the daemon and a real executor process (on each step
    core): the child retries a stop, the daemon a report; health() (the status's ``steps``)
    counts both, and each record is taken once it is whole."""
    hw, ex = process_executor("mock", core=step_core)
    try:
        ex.start()
        counters = ex.health().counters
        assert (counters["ring_retries_segments"], counters["ring_retries_reports"]) == (0, 0)
        # daemon -> child: a hard stop of motor 0 announced, only its sequence number there
        stops = ex.shared.stops
        index = stops.cells[0]
        at = slot_offset(stops, index)
        old = bytes(stops.buf[at : at + stops.slot])
        whole = slot_bytes(stops, index, (0, 5, -1))
        show_slot(stops, index, whole[:8] + old[8:])
        ex._kick()
        until("the executor's retry", lambda: ex.health().counters["ring_retries_segments"] >= 1)
        assert stops.cells[1] == index  # not taken torn
        stops.buf[at : at + stops.slot] = whole
        ex._kick()
        seen: list[ExecEvent] = []

        def reported() -> bool:  # the stop taken whole: its STOPPED report
            seen.extend(ex.events())
            return bool(seen)

        until("the report of the stop", reported, timeout=60.0)
        assert [(e.kind, e.motor, e.gen) for e in seen] == [(ExecEventKind.STOPPED, 0, 5)]
        assert ex.health().counters["ring_retries_reports"] == 0
        # child -> daemon: a report whose record is new and its check still the old one
        events = ex.shared.events
        index = events.cells[0]
        at = slot_offset(events, index)
        old = bytes(events.buf[at : at + events.slot])
        fields = (EVENT_KINDS.index(ExecEventKind.STOPPED), 0, 9, 0, 0, 1, 0, 0.0, b"torn")
        whole = slot_bytes(events, index, fields)
        show_slot(events, index, whole[: EVENT_RECORD.size] + old[EVENT_RECORD.size :])
        assert ex.events() == [] and ex.events() == []
        assert ex.health().counters["ring_retries_reports"] == 2
        events.buf[at : at + events.slot] = whole
        assert [(e.kind, e.motor, e.gen) for e in ex.events()] == [(ExecEventKind.STOPPED, 0, 9)]
        assert ex.health().counters["ring_retries_reports"] == 2
    finally:
        ex.close()
        hw.close()
    after = ex.health().counters  # plain copies once closed
    assert after["ring_retries_segments"] >= 1 and after["ring_retries_reports"] == 2


# ---------------------------------------------------------------- what real time it got


def vm_locked_kib(pid: int) -> int:
    """The process's locked memory (``VmLck`` of /proc/PID/status), in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmLck for {pid}")


def test_the_daemon_learns_what_real_time_the_executor_process_got() -> None:
    """The executor process asks for SCHED_FIFO 50, which its kernel refuses (EPERM,
    injected at os.sched_setscheduler in its interpreter), for CPU 1023, which the kernel
    refuses for real, and for mlockall, which the kernel grants or refuses as this test's
    limits say: the daemon's side reads each back, with the reason and the fix, and each
    is what the kernel did to that process."""
    rt = RealtimeOptions(priority=50, lock_memory=True, cpu=1023)
    hw, ex = process_executor("mock", rt=rt, process=interpreter_with(REFUSE_SCHED_FIFO))
    try:
        assert ex.realtime() is None  # not started yet
        ex.start()
        got = ex.realtime()
        assert got is not None and ex.pid is not None
        assert "sched_fifo" in got.refused() and "cpu_affinity" in got.refused()
        fifo, cpu, memory = got.sched_fifo, got.cpu_affinity, got.memory_lock
        assert (fifo.what, fifo.error) == ("SCHED_FIFO 50", "EPERM") and fifo.fix
        assert (cpu.what, cpu.error) == ("CPU 1023", "EINVAL") and cpu.fix
        assert os.sched_getscheduler(ex.pid) == os.SCHED_OTHER  # refused indeed
        assert os.sched_getaffinity(ex.pid) != {1023}
        locked = vm_locked_kib(ex.pid) > 0
        assert memory.state == ("granted" if locked else "refused"), (memory, locked)
        assert got.kernel == os.uname().release
    finally:
        ex.close()
        hw.close()


def test_an_executor_asking_for_nothing_says_so() -> None:
    hw, ex = process_executor("mock")  # RealtimeOptions(priority=0, lock_memory=False)
    try:
        ex.start()
        got = ex.realtime()
        assert got is not None and got.refused() == []
        assert {o.state for o in got.outcomes().values()} == {"not asked"}
        assert got.words().startswith("real time not asked ([step_thread] cpu = -1")
    finally:
        ex.close()
        hw.close()
