"""The mock backend's own parts: the step timeline written to a file (what the process step
executor's child leaves for the tests to read). The mock's behaviour as hardware is the
backend contract's (tests/contract); the engine's tests run on it throughout."""

from __future__ import annotations

import json
from pathlib import Path

from motorctl.hal.backends.mock.backend import (
    build,
    build_step_io,
    mock_axis,
    read_timeline,
    world_of,
)
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.spec import HardwareSpec
from tests.support.rigs import FAR


def test_timeline_file_round_trip(tmp_path: Path) -> None:
    clock = VirtualClock()
    path = tmp_path / "t.jsonl"
    spec = HardwareSpec(axes=(FAR,), options={"timeline_file": str(path)})
    io = build_step_io(spec, clock, None)
    io.outputs.set_direction(0, True)
    io.outputs.pulse([0], 1e-6)
    io.close()
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert [k for _, k, _, _ in lines] == ["dir", "step"]
    assert read_timeline(str(path)).step_times(0) == [clock.now()]


def test_mock_stall_only_while_driven_past_the_stop() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(mock_axis(endstop_min=-5, endstop_max=5),))
    hw = build(spec, clock)
    world = world_of(hw)
    out, driver = build_step_io(spec, clock, hw).outputs, hw.steppers[0].driver
    out.set_direction(0, True)
    for _ in range(5):
        out.pulse([0], 1e-6)
    assert not driver.status().stall and world.axes[0].position == 5
    out.pulse([0], 1e-6)
    assert driver.status().stall  # pushed past the max stop
    out.set_direction(0, False)
    assert not driver.status().stall  # backing out
    world.inject_stall(0, True)
    assert driver.status().stall
    world.inject_stall(0, False)
    for _ in range(12):
        out.pulse([0], 1e-6)
    assert world.axes[0].position == -6 and driver.status().stall
    spec2 = HardwareSpec(axes=(mock_axis(invert_dir=True, endstop_max=0),))
    hw2 = build(spec2, clock)
    out2 = build_step_io(spec2, clock, hw2).outputs
    out2.set_direction(0, True)
    out2.pulse([0], 1e-6)
    assert hw2.steppers[0].driver.status().stall  # logical direction, not the DIR level
