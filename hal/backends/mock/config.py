"""The mock backend's declaration (:class:`MockDeclaration`, hal/contract.py): its config
sections, the simulated world ([mock]) and axes ([motors.mock]), and whether its motors
lose steps.

Declared here, not in the daemon's core schema: the mock backend owns them; the registry
names this declaration in `motorctl.hal.registry.BACKENDS`. Like every declaration it imports
no hardware library, so a config can be checked without loading any backend.

Pure declarations: no state, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from motorctl.hal.contract import BackendDeclaration, DriverLookup
from motorctl.hal.spec import HardwareSpec
from motorctl.schema import (
    Extension,
    Rule,
    Sectioned,
    Violation,
    boolean,
    integer,
    pairs,
    section,
)

# The simulated end stops sit inside the protocol's 24-bit position range (PROTOCOL.md §3).
# hal may not import protocol, so the range is written out here and checked against
# motorctl.protocol.codec.POS_MIN/POS_MAX by tests/daemon/test_config.py.
POSITION_MIN = -(1 << 23)
POSITION_MAX = (1 << 23) - 1
#: where the simulated end stops sit without a [motors.mock] table
ENDSTOP_MIN = -10_000
ENDSTOP_MAX = 10_000


def _endstops_ordered(v: Mapping[str, Any]) -> Violation | None:
    lo, hi = v["endstop_min"], v["endstop_max"]
    if lo >= hi:
        return ("endstop_min", lo, f"not below endstop_max = {hi}")
    return None


@section(
    "The simulated axis (mock backend only).",
    rules=(Rule(("endstop_min", "endstop_max"), "endstop_min < endstop_max", _endstops_ordered),),
    notes="""\
The simulated axis starts at position 0; its end stops sit at `endstop_min` and
`endstop_max`. Only `endstop_min < endstop_max` is required, so both may lie on the same side
of the start. Each end stop is

- a switch (its end-stop input), active at that position and every position beyond it, with
  no hysteresis: one step back from it releases it. Homing on it (InitMove) makes the first
  position off it 0: `endstop_min + 1` homing down, `endstop_max - 1` homing up;
- and a hard stop at the same position: a step pulse that would take the axis further out is
  lost (the daemon still counts it), and the motor's driver reports a stall while it keeps
  pushing that way; what stall homing (`homing.source = "stall"`) finds. Coming back to the
  hard stop without pushing is no stall.

`switches = false` leaves out the switches (the inputs never activate): an axis homed by
stall, which has no switch, else a MoveTo back to the stall's position 0 ends on the switch
there: an end stop hit (E4).""",
)
@dataclass(frozen=True)
class MockAxisConfig:
    """[motors.mock]: the simulated axis of one motor."""

    endstop_min: int = integer(
        ENDSTOP_MIN,
        POSITION_MIN,
        POSITION_MAX,
        "Position of the simulated end stop below, relative to the start position 0.",
    )
    endstop_max: int = integer(
        ENDSTOP_MAX,
        POSITION_MIN,
        POSITION_MAX,
        "Position of the simulated end stop above, relative to the start position 0.",
    )
    switches: bool = boolean(
        True,
        "false: the end stops are hard stops only, with no switch (the end-stop inputs never "
        "activate): an axis homed by stall.",
    )


@section(
    "The simulated world of the mock backend. Absent: no wires.",
    notes="""\
A wire joins two pins: reading one that is an input gives the level of the other while it
is an output. Both pins must be listed in `[[pins]]`, and each pin may be in one wire only.
Without a `[mock]` table there are no wires; a `[mock]` table without `wires` gets the
default `[[0, 4], [1, 5], [2, 6], [3, 7]]`, which needs pins 0-7.""",
)
@dataclass(frozen=True)
class MockConfig:
    """[mock]: wiring of the simulated world."""

    lose_steps: bool = boolean(
        False,
        "Simulate motors that can lose steps: a late step whose lag is beyond a motor's "
        "max_lag_full_steps stops it with E4 'step timing lost', as on real hardware (tests of "
        "the fail-safe). false: the simulated motors have no rotor; a late step is counted "
        "and the move slides, never a fault.",
    )
    wires: tuple[tuple[int, int], ...] = pairs(
        [[0, 4], [1, 5], [2, 6], [3, 7]],
        "Pins joined by a wire: an input reads the output it is wired to. This default "
        "applies only when a [mock] table is written; without [mock] there are no wires.",
    )


def _wires_on_pins(v: Mapping[str, Any]) -> Violation | None:
    numbers = {pin.number for pin in v["pins"]}
    for i, wire in enumerate(v["mock"].wires):
        for pin in wire:
            if pin not in numbers:
                listed = ", ".join(str(n) for n in sorted(numbers)) or "none"
                problem = f"pin {pin} is not in [[pins]] (configured pins: {listed})"
                return (f"mock.wires[{i}]", list(wire), problem)
    return None


def _wires_disjoint(v: Mapping[str, Any]) -> Violation | None:
    seen: dict[int, int] = {}
    for i, wire in enumerate(v["mock"].wires):
        for pin in wire:
            if pin in seen:
                where = "this wire" if seen[pin] == i else f"mock.wires[{seen[pin]}]"
                return (f"mock.wires[{i}]", list(wire), f"pin {pin} is also in {where}")
            seen[pin] = i
    return None


def motors_lose_steps(spec: Sectioned) -> bool:
    """``[mock] lose_steps``: whether the simulated motors may lose steps as real ones
    (False without a [mock] table)."""
    world = spec.sections.get(MockConfig)
    return isinstance(world, MockConfig) and world.lose_steps


class MockDeclaration(BackendDeclaration):
    """The mock backend's sections: ``[mock]`` and ``[motors.mock]``."""

    def sections(self, drivers: DriverLookup) -> tuple[Extension, ...]:
        return (
            Extension(
                "",
                "mock",
                MockConfig,
                owner="the mock backend",
                absent={"wires": [], "lose_steps": False},
                absent_text="no wires",
                rules=(
                    Rule(("mock.wires",), "every wired pin is listed in [[pins]]", _wires_on_pins),
                    Rule(("mock.wires",), "each pin in at most one wire", _wires_disjoint),
                ),
            ),
            Extension("motors", "mock", MockAxisConfig, owner="the mock backend"),
        )

    def motors_lose_steps(self, spec: HardwareSpec) -> bool:
        return motors_lose_steps(spec)
