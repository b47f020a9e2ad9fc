"""The contract harness for the gpiod backend on gpio-sim (inside the VM only)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

from hwtest import gsim
from hwtest.layout import DC, MOTORS, PINS, axis_section, pin_section, top_section, where
from motorctl.hal.backends.gpiod.config import GpiodAxisConfig, GpiodConfig, GpiodPinConfig
from motorctl.hal.interfaces import BridgeState
from motorctl.hal.spec import HardwareSpec, PinSpec
from tests.contract.harness import Harness

LEVELS = {
    (True, False, True): BridgeState.FORWARD,
    (False, True, True): BridgeState.REVERSE,
    (True, True, True): BridgeState.BRAKE,
    (False, False, False): BridgeState.COAST,
}


class GpiodHarness(Harness):
    backend = "gpiod"

    def __init__(self) -> None:
        super().__init__()
        self.api = os.environ.get("MOTORCTL_GPIOD_API", "auto")
        self.name = f"gpiod-{self.api}"

    def spec(
        self,
        motors: int,
        pins: Sequence[PinSpec],
        dc: bool,
        endstop_active_low: bool = False,
        invert_dir: bool = False,
    ) -> HardwareSpec:
        base = super().spec(motors, pins, dc, endstop_active_low, invert_dir)
        axes = tuple(
            dataclasses.replace(a, sections={GpiodAxisConfig: axis_section(i)})
            for i, a in enumerate(base.axes)
        )
        wired = tuple(
            dataclasses.replace(p, sections={GpiodPinConfig: pin_section(p.number)})
            for p in base.pins
        )
        return dataclasses.replace(
            base, axes=axes, pins=wired, sections={GpiodConfig: top_section(self.api)}
        )

    def drive_pin(self, number: int, level: bool) -> None:
        chip, off = where(PINS[number])
        gsim.sim_pull(off, level, chip)

    def pin_level(self, number: int) -> bool:
        chip, off = where(PINS[number])
        return gsim.sim_value(off, chip)

    def drive_endstop(self, motor: int, which: str, level: bool) -> None:
        chip, off = where(MOTORS[motor][3 if which == "min" else 4])
        gsim.sim_pull(off, level, chip)

    def dir_level(self, motor: int) -> bool:
        chip, off = where(MOTORS[motor][1])
        return gsim.sim_value(off, chip)

    def count_steps(self) -> None:
        gsim.trace_start()

    def steps(self, motor: int) -> int:
        chip, off = where(MOTORS[motor][0])
        events = gsim.trace_read()
        assert gsim.trace_lost() == 0, "the trace lost events: size the buffer"
        return sum(1 for e in gsim.sets(events, gsim.chip_base(chip) + off) if e.value == 1)

    def bridge(self) -> BridgeState:
        levels = tuple(gsim.sim_value(where(x)[1], where(x)[0]) for x in DC)
        return LEVELS[(levels[0], levels[1], levels[2])]
