"""The mock backend (backend.py) as the registry builds it: the step timeline written to a
file (what the process step executor's child leaves for the tests to read), the lines it
offers a compiled core, ``--probe`` of a backend that opens nothing. The mock's behaviour as
hardware is the backend contract's (tests/contract); the engine's tests run on it throughout."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from motorctl.hal.backends.mock.world import mock_axis, read_timeline
from motorctl.hal.compiled_lines import SimulatedLines
from motorctl.hal.contract import ProbeReport
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.tmc.settings import TmcSettings, TmcSpec
from motorctl.hal.layers.tmc.tmc5160 import TMC5160
from motorctl.hal.registry import backend
from motorctl.hal.spec import HardwareSpec
from tests.support import REPO
from tests.support.mock_factory import MockFactory
from tests.support.rigs import FAR


def test_timeline_file_round_trip(tmp_path: Path, mock_factory: MockFactory) -> None:
    clock = VirtualClock()
    path = tmp_path / "t.jsonl"
    spec = HardwareSpec(axes=(FAR,), options={"timeline_file": str(path)})
    io = mock_factory.step_io(spec, clock)
    io.outputs.set_direction(0, True)
    io.outputs.pulse([0], 1e-6)
    io.close()
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert [k for _, k, _, _ in lines] == ["dir", "step"]
    assert read_timeline(str(path)).step_times(0) == [clock.now()]


def test_its_compiled_lines_are_the_worlds_mechanics_of_the_stepped_axes(
    mock_factory: MockFactory,
) -> None:
    """A motor whose driver chip runs its own ramp is not the step executor's: the compiled
    core's motor 0 is axis 1 here, as the Python parts' motor 0 is."""
    ramp = mock_axis(driver=TmcSpec("/dev/spidev0.0", TmcSettings(chip=TMC5160), ramp=True))
    io = mock_factory.step_io(HardwareSpec((ramp, mock_axis(endstop_min=-5, endstop_max=7))))
    lines = io.compiled
    assert isinstance(lines, SimulatedLines), io.compiled_missing
    assert lines.axis_of == (1,) and lines.endstops[1] == (-5, 7)
    assert io.compiled_text() == "the simulated mechanics of the mock"


def test_probe_of_the_mock_says_nothing_is_opened() -> None:
    report = ProbeReport()
    backend("mock").probe(HardwareSpec((mock_axis(),)), VirtualClock(), report)
    assert report.sections == [("backend mock", ["nothing to probe: no hardware is opened"])]
    assert report.compiled_lines == "the simulated mechanics of the mock"
    assert report.problems == []
    out = subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.main", "--probe", "--latency-seconds", "0"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "backend mock:\n  nothing to probe" in out.stdout
