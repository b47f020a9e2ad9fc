"""Loading the compiled step core (motion/executors/compiled_core.py): the build matches the
Python side's cells, another build named by MOTORCTL_STEPCORE that is not there is "not
built" with its path, and a step IO that hands over no lines is refused with its reason.
(The core's behaviour, on both cores: test_step_core.py.)"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from motorctl.hal.backends.mock.backend import build, build_step_io
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.executors import compiled_core
from motorctl.motion.executors.core_cells import COUNTER_NAMES, MOTOR_CELLS
from motorctl.motion.executors.process.rings import Layout, Shared
from motorctl.motion.latency import CELLS
from tests.support.motor_defaults import motor_limits
from tests.support.rigs import FAR


def test_the_build_matches_the_python_sides_cells() -> None:
    mod = compiled_core.load()
    assert (
        len(COUNTER_NAMES),
        MOTOR_CELLS,
        CELLS,
    ) == (mod.COUNTERS, mod.MOTOR_CELLS, mod.LATENCY_CELLS)
    assert compiled_core.unavailable() is None


def test_a_build_that_is_not_there_is_not_built(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv(compiled_core.ENV, str(tmp_path / "missing.so"))
    with pytest.raises(ImportError):
        compiled_core.load()
    why = compiled_core.unavailable()
    assert why is not None and why.startswith("the compiled step core is not built")
    assert "missing.so" in why and "gcc and the Python headers" in why


def test_a_step_io_without_lines_for_it_is_refused_with_its_reason() -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,))
    hw = build(spec, clock)
    io = replace(build_step_io(spec, clock, hw), compiled=None, compiled_missing="kept")
    layout = Layout(1, len(io.inputs.names))
    shm = SharedBlock.create(layout.size, "motorctl-test-core")
    shared = Shared(shm, layout)
    try:
        assert compiled_core.unavailable(io) == "kept"
        with pytest.raises(ValueError, match="no lines for a compiled core: kept"):
            compiled_core.CompiledStepCore(io, [motor_limits(1e-4)], shared)
        with pytest.raises(ValueError, match="2 motors configured, the step IO drives 1"):
            compiled_core.CompiledStepCore(io, [motor_limits(1e-4)] * 2, shared)
    finally:
        shared.release()
        shm.close()
        io.close()
        hw.close()
