"""The mock backend's own parts: the step timeline written to a file (what the process step
executor's child leaves for the tests to read). The mock's behaviour as hardware is the
backend contract's (tests/contract); the engine's tests run on it throughout."""

from __future__ import annotations

import json
from pathlib import Path

from motorctl.hal.backends.mock.world import build_step_io, read_timeline
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
