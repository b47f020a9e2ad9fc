"""The step cores on a real kernel GPIO chip (gpio-sim, inside the VM: hwtest/run). The
compiled one,
with the libgpiod API the run chose: the gpiod backend hands its line requests over (uAPI v2
requests, or v1 handles and event requests), and the core's own ioctls reach the lines:
every pulse is in the kernel's gpio_value trace, the STEP lines of one chip rise in one
call, DIR is set before the steps, an edge the sim makes on an end stop is read from the
kernel's edge events; it runs on a virtual clock here (its edges as fast as the ioctls go),
the daemon's tests (test_daemon.py) run it on the real clock, as the daemon's default. The
Python one, asked for in the config, makes the same pulses through libgpiod's binding."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwtest import gsim
from hwtest.gpiod_harness import GpiodHarness
from hwtest.layout import GUEST_READY_TIMEOUT_S, MOTORS, where
from hwtest.test_daemon import example_config
from motorctl.hal.backends.gpiod.chip import load_api
from motorctl.hal.compiled_lines import ChardevLines
from motorctl.hal.interfaces import Hardware, StepIO, VirtualClock
from motorctl.hal.registry import open_hardware, open_step_io
from motorctl.hal.shm import SharedBlock
from motorctl.motion.executors.base import ExecEvent, ExecEventKind, to_ticks
from motorctl.motion.executors.compiled_core import CompiledStepCore
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.process.rings import Layout, Shared, segment_fields
from motorctl.motion.executors.segments import StepSegment
from tests.support.daemon_proc import DaemonProcess
from tests.support.motor_defaults import motor_params

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")
K = ExecEventKind


@dataclass
class Rig:
    hw: Hardware
    io: StepIO
    shared: Shared
    core: CompiledStepCore
    events: list[ExecEvent]

    def push(self, motor: int, seg: StepSegment) -> None:
        assert self.shared.segs[motor].put(*segment_fields(seg))


def gpio(line: str) -> int:
    chip, off = where(line)
    return gsim.chip_base(chip) + off


@pytest.fixture
def rig() -> Iterator[Rig]:
    for m in MOTORS:
        for line in (m[3], m[4]):
            chip, off = where(line)
            gsim.sim_pull(off, False, chip)  # end stops clear (active high here)
    # a virtual clock ahead of the kernel's: an edge's timestamp is never in its future
    clock = VirtualClock(time.monotonic() + 3600.0)
    spec = GpiodHarness().spec(3, [], False)
    hw = open_hardware("gpiod", spec, clock)
    io = open_step_io("gpiod", spec, clock, parent=hw)
    layout = Layout(3, len(io.inputs.names))
    shm = SharedBlock.create(layout.size, "motorctl-hwtest")
    shared = Shared(shm, layout)
    events: list[ExecEvent] = []
    limits = axis_limits([motor_params(max_speed=20_000.0)] * 3, 0.0, lag_faults=False)
    core = CompiledStepCore(io, limits, shared, emit=events.append)
    try:
        yield Rig(hw, io, shared, core, events)
    finally:
        core.close()
        shared.release()
        shm.close()
        io.close()
        hw.close()


def test_the_backend_hands_its_line_requests_to_the_compiled_core(rig: Rig) -> None:
    lines = rig.io.compiled
    assert isinstance(lines, ChardevLines), rig.io.compiled_missing
    uapi = {"v2": 2, "v1": 1}[load_api(API).name]
    assert [r.uapi for r in lines.outputs] == [uapi]  # every STEP/DIR/ENABLE on gpiochip0
    assert all(r.uapi == uapi for r in lines.inputs)
    # end stops: v2 one request per chip, v1 one per line
    assert len(lines.inputs) == (2 if uapi == 2 else 6)
    assert sorted(n for nums in lines.input_lines for n in nums) == list(range(6))


def test_every_pulse_reaches_the_lines_and_one_call_raises_every_due_step(rig: Rig) -> None:
    t0 = rig.core.clock.now_ns() + 1_000_000
    for m in range(3):
        rig.push(m, StepSegment(t0, 500_000, 20, 0, 1, 1))
        rig.push(m, StepSegment(t0 + 20 * 500_000, 500_000, 10, 0, -1, 1, True))
    gsim.trace_start()
    rig.core.run_until(t0 + 40 * 500_000)
    gsim.trace_stop()
    events = gsim.trace_read()
    assert gsim.trace_lost() == 0
    assert [(e.kind, e.motor, e.position) for e in rig.events] == [
        (K.DONE, m, 10) for m in range(3)
    ]
    # the STEP lines' changes in the order the kernel made them (a v1 handle writes every
    # line of it at each call: DIR writes set the STEP lines again, at 0)
    level = {gpio(m[0]): 0 for m in MOTORS}
    on_steps = []
    for e in events:
        if e.gpio in level and e.op == "set" and e.value != level[e.gpio]:
            level[e.gpio] = e.value
            on_steps.append(e)
    assert len(on_steps) == 3 * 2 * 30
    for i in range(0, len(on_steps), 6):  # each pulse: three rises, then three falls
        assert [e.value for e in on_steps[i : i + 6]] == [1, 1, 1, 0, 0, 0], i
    for lines in MOTORS:
        rises = [e for e in gsim.changes(gsim.sets(events, gpio(lines[0]))) if e.value == 1]
        dirs = gsim.changes(gsim.sets(events, gpio(lines[1])))
        assert len(rises) == 30
        down = [e for e in dirs if e.value == 0 and e.ts > rises[0].ts]  # (v1: rewrites)
        assert len(down) == 1 and rises[19].ts < down[0].ts < rises[20].ts
        assert gsim.sim_value(where(lines[1])[1]) is False
    assert list(rig.shared.positions) == [10, 10, 10]


def test_an_end_stop_edge_from_the_kernel_stops_the_motor_stepping_toward_it(rig: Rig) -> None:
    t0 = rig.core.clock.now_ns() + 1_000_000
    rig.push(0, StepSegment(t0, 1_000_000, 100, 0, -1, 1, True))
    rig.push(1, StepSegment(t0, 1_000_000, 30, 0, -1, 1, True))
    rig.core.run_until(t0 + 10 * 1_000_000)
    chip, off = where(MOTORS[0][3])
    gsim.sim_pull(off, True, chip)  # motor 0's min end stop (active high) triggers
    time.sleep(0.05)  # the kernel's edge event is queued by then
    rig.core.run_until(t0 + 200 * 1_000_000)
    kinds = [(e.kind, e.motor) for e in rig.events]
    assert (K.ENDSTOP, 0) in kinds and (K.DONE, 1) in kinds
    stop = next(e for e in rig.events if e.kind is K.ENDSTOP)
    assert stop.direction == -1 and -13 <= stop.position <= -11  # the next step saw it
    assert rig.shared.positions[0] == stop.position and rig.shared.positions[1] == -30
    line = rig.io.endstops[0][0]
    assert line is not None and rig.shared.levels[line] == 1  # published for the daemon
    assert to_ticks(stop.t) <= rig.core.clock.now_ns()


def test_a_release_edge_from_the_kernel_stops_the_back_off_where_it_released(rig: Rig) -> None:
    """Homing's back-off (a plan that watches for the release): motor 0 leaves its pressed
    min end stop upward; the kernel's edge when the sim lets go of it stops the motor at the
    next step, RELEASED with where it was first seen off it."""
    chip, off = where(MOTORS[0][3])
    gsim.sim_pull(off, True, chip)  # motor 0's min end stop (active high) is pressed
    time.sleep(0.05)  # the kernel's edge event is queued by then
    t0 = rig.core.clock.now_ns() + 1_000_000
    rig.push(0, StepSegment(t0, 1_000_000, 100, 0, 1, 1, True, True, True))
    rig.core.run_until(t0 + 10 * 1_000_000)
    assert rig.events == []  # still on it: backing off
    gsim.sim_pull(off, False, chip)  # released
    time.sleep(0.05)
    rig.core.run_until(t0 + 200 * 1_000_000)
    assert [(e.kind, e.motor) for e in rig.events] == [(K.RELEASED, 0)]
    ev = rig.events[0]
    assert ev.direction == -1 and 11 <= ev.mark <= 13  # the next step saw it
    assert ev.position == ev.mark == rig.shared.positions[0]  # no debounce: stopped there
    line = rig.io.endstops[0][0]
    assert line is not None and rig.shared.levels[line] == 0


def test_the_python_core_asked_for_makes_the_same_pulses(tmp_path: Path) -> None:
    """[step_thread] core = "python" in the daemon: the reference core, through libgpiod's
    binding, on the example's lines."""
    for m in MOTORS:
        chip, off = where(m[3])
        gsim.sim_pull(off, True, chip)  # the example's end stops are active low: clear
    text = example_config().replace("[step_thread]", '[step_thread]\ncore = "python"', 1)
    d = DaemonProcess(tmp_path, text, ready_timeout=GUEST_READY_TIMEOUT_S).start()
    try:
        assert "; step core python;" in d.ready_line
        assert d.status()["executor"]["core"] == "python"
        step = gpio(MOTORS[0][0])
        with d.client(timeout=10.0) as c:
            start = c.position(0)
            gsim.trace_start()
            c.move_to(0, start + 150)
            c.wait_moved(0, 30_000)
            gsim.trace_stop()
            assert c.position(0) == start + 150
        events = gsim.trace_read()
        assert gsim.trace_lost() == 0
        assert len([e for e in gsim.changes(gsim.sets(events, step)) if e.value == 1]) == 150
    finally:
        d.close()
