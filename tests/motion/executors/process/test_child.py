"""The executor process (motion/executors/process/child.py): which step core it runs over
the lines its backend hands over (``choose_core``, and the note it leaves the daemon), and
the records it takes from the daemon's rings checked before any step: a bad one faults its
motor (every motor for a stop whose motor is unknown), counted, and the process lives on.
(The child's start and death as the daemon sees them: test_parent.py.)"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import pytest

from motorctl.hal.backends.mock.backend import build, build_step_io
from motorctl.hal.interfaces import StepIO, VirtualClock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.executors.base import ExecEvent, ExecEventKind
from motorctl.motion.executors.process.child import choose_core
from tests.support.executors import process_executor
from tests.support.rigs import FAR
from tests.support.wait import until


def test_a_bad_record_from_the_daemon_faults_its_motor_in_the_executor_process(
    step_core: str,
) -> None:
    """Records whose CRC is right but whose fields no planner makes, into a real executor
    process (on each step core): a segment with direction 5 faults its motor, a stop for
    motor 7 (there are 2) faults every motor; the process lives on and counts them."""
    hw, ex = process_executor("mock", core=step_core, motors=2)
    try:
        ex.start()
        assert ex.shared.segs[1].put(10**9, 1000, 3, 0, 5, 1, 0)
        ex._kick()
        got: list[ExecEvent] = []

        def events(n: int) -> bool:
            got.extend(ex.events())
            return len(got) >= n

        until("the segment's fault", lambda: events(1))
        assert [(e.kind, e.motor) for e in got] == [(ExecEventKind.FAULT, 1)]
        assert got[0].detail == "bad step segment record in the executor's ring: direction 5"
        assert ex.shared.stops.put(7, 1, -1)
        ex._kick()
        got.clear()
        until("the stop's faults", lambda: events(2))
        assert sorted((e.kind, e.motor) for e in got) == [
            (ExecEventKind.FAULT, 0),
            (ExecEventKind.FAULT, 1),
        ]
        assert all(e.detail.endswith("stop record in the executor's ring: motor 7") for e in got)
        health = ex.health()
        assert health.alive and health.counters["bad_records"] == 2
        assert health.counters["steps"] == 0
    finally:
        ex.close()
        hw.close()


# ---------------------------------------------------------------- which step core


@pytest.fixture
def mock_io() -> Iterator[StepIO]:
    """The mock's step IO (it hands its simulated lines to a compiled core)."""
    clock = VirtualClock()
    spec = HardwareSpec(axes=(FAR,))
    hw = build(spec, clock)
    io = build_step_io(spec, clock, hw)
    yield io
    io.close()
    hw.close()


def test_python_asked_for_is_the_python_core_whatever_is_built(mock_io: StepIO) -> None:
    assert choose_core("python", mock_io) == ("python", 'as [step_thread] core = "python" asks')


def test_auto_and_compiled_take_the_compiled_core_over_lines_it_is_handed(
    mock_io: StepIO,
) -> None:
    assert mock_io.compiled is not None
    assert choose_core("auto", mock_io) == ("compiled", "its lines: the mock")
    assert choose_core("compiled", mock_io) == ("compiled", "its lines: the mock")


def test_without_lines_auto_falls_back_to_python_and_compiled_cannot_start(
    mock_io: StepIO,
) -> None:
    bare = replace(mock_io, compiled=None, compiled_missing="the backend keeps its lines")
    assert choose_core("auto", bare) == (
        "python",
        "not the compiled core: the backend keeps its lines",
    )
    assert choose_core("compiled", bare) == (
        None,
        '[step_thread] core = "compiled", but the backend keeps its lines',
    )


def test_a_core_of_another_name_cannot_start(mock_io: StepIO) -> None:
    assert choose_core("fast", mock_io) == (None, "[step_thread] core = 'fast': no such step core")
