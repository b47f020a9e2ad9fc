"""The backend contract (contract.py) itself: what a backend gets without writing it (the
optional parts' defaults), what its public ``open_step_io`` adds to its hook, and the
``--probe`` report with its problems as data. (How every backend's parts behave is
tests/contract/, run on the mock here and on gpio-sim in the hardware tier.)"""

from __future__ import annotations

import pytest

from motorctl.hal.backends.mock.backend import MockBackend
from motorctl.hal.backends.mock.world import mock_axis
from motorctl.hal.compiled_lines import NO_COMPILED_LINES, CompiledLines
from motorctl.hal.contract import (
    Backend,
    BackendDeclaration,
    ChipTable,
    DriverLookup,
    LayerDeclaration,
    ProbeReport,
    Problem,
    ProblemKind,
)
from motorctl.hal.interfaces import Clock, Hardware, StepIO, VirtualClock
from motorctl.hal.spec import HardwareSpec
from motorctl.schema import Extension


class Bare(Backend):
    """A backend that writes only the two required parts (the mock's, borrowed)."""

    name = "bare"

    def build(self, spec: HardwareSpec, clock: Clock) -> Hardware:
        return MockBackend().build(spec, clock)

    def build_step_io(self, spec: HardwareSpec, clock: Clock, parent: Hardware | None) -> StepIO:
        return MockBackend().build_step_io(spec, clock, parent)


class Failing(Bare):
    """A backend whose compiled lines cannot be had: what it opened is closed again."""

    closed = 0

    def build_step_io(self, spec: HardwareSpec, clock: Clock, parent: Hardware | None) -> StepIO:
        io = super().build_step_io(spec, clock, parent)
        io.closers.append(self.count)
        return io

    def count(self) -> None:
        Failing.closed += 1

    def compiled_lines(self, io: StepIO) -> CompiledLines | str:
        raise RuntimeError("cannot look")


SPEC = HardwareSpec((mock_axis(),))


def test_a_backend_without_compiled_lines_says_so() -> None:
    io = Bare().open_step_io(SPEC, VirtualClock())
    try:
        assert io.compiled is None and io.compiled_missing == NO_COMPILED_LINES
        assert io.compiled_text() == f"none ({NO_COMPILED_LINES})"
    finally:
        io.close()


def test_the_step_io_is_closed_when_its_compiled_lines_fail() -> None:
    with pytest.raises(RuntimeError, match="cannot look"):
        Failing().open_step_io(SPEC, VirtualClock())
    assert Failing.closed == 1


def test_a_backend_without_a_probe_says_it_opens_nothing() -> None:
    report = ProbeReport()
    Bare().probe(SPEC, VirtualClock(), report)
    assert report.sections == [("backend bare", ["nothing to probe: no hardware is opened"])]
    assert report.compiled_lines == f"none ({NO_COMPILED_LINES})" and report.problems == []


def test_the_declarations_defaults() -> None:
    class Sections(BackendDeclaration):
        def sections(self, drivers: DriverLookup) -> tuple[Extension, ...]:
            return ()

    class Layered(LayerDeclaration):
        def sections(self) -> tuple[Extension, ...]:
            return ()

        def applies(self, spec: HardwareSpec) -> bool:
            return False

    assert Sections().motors_lose_steps(SPEC)  # real rotors, unless a backend says not
    assert Layered().driver_spec(object()) is None  # type: ignore[arg-type]


def test_the_report_prints_its_sections_then_its_problems() -> None:
    report = ProbeReport()
    report.add("chips", ["gpiochip0 [sim] 32 lines"])
    report.add("empty", [])
    report.problem("line GPIO3 is used twice", ProblemKind.CONFIG)
    report.problem("/dev/spidev0.0 does not exist")
    assert report.text() == (
        "chips:\n  gpiochip0 [sim] 32 lines\nempty:\n"
        "PROBLEM: line GPIO3 is used twice\nPROBLEM: /dev/spidev0.0 does not exist\n"
    )
    assert report.problems == [
        Problem("line GPIO3 is used twice", ProblemKind.CONFIG),
        Problem("/dev/spidev0.0 does not exist", ProblemKind.DEVICE),
    ]
    assert str(report.problems[0]) == "line GPIO3 is used twice"


def test_a_chip_table_names_its_chips_without_loading_them_and_loads_on_the_first_asked() -> None:
    loads: list[int] = []

    def load() -> dict[str, int]:
        loads.append(1)
        return {"a": 1, "b": 2}

    table = ChipTable(("a", "b"), load)
    assert (tuple(table), len(table), "a" in table, "c" in table) == (("a", "b"), 2, True, False)
    assert not loads  # names, membership and length load nothing
    assert table["b"] == 2 and loads
    with pytest.raises(KeyError):
        table["c"]


def test_a_chip_table_that_names_other_chips_than_it_loads_says_so() -> None:
    table = ChipTable(("a", "c"), lambda: {"a": 1, "b": 2})
    with pytest.raises(RuntimeError, match=r"the chips are \('a', 'b'\), the table names"):
        table["a"]
