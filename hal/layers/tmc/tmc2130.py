"""The TMC2130 (datasheet rev. 1.15): its registers and fields, and its :class:`Chip`.

A STEP/DIR driver with an SPI configuration and status interface, no ramp generator: the
shared driver (``driver.py``) drives it whole; what is the TMC2130's own is here: the sense
voltage range CHOPCONF.vsense its current scaling picks, its readable registers, its four
SPI status bits. The registers and fields both chips have are in ``fields.py``. Pure data
and formulas: any thread.
"""

from __future__ import annotations

import math
from typing import Final

from motorctl.hal.layers.tmc import fields
from motorctl.hal.layers.tmc.fields import (
    DRV_FLAGS,
    SHORTS_TO_GROUND,
    Chip,
    CurrentSetting,
    Field,
    check_currents,
    current_scale,
    register_names,
)


class Reg(fields.Reg):
    """The TMC2130's registers that motorctl uses: all shared with the TMC5160."""


class F(fields.F):
    """The shared fields and the TMC2130's own, each keyed by its register."""

    VSENSE: Final = Field(Reg.CHOPCONF, 17)  # the sense voltage range: 1 = high sensitivity


#: full-scale sense voltages [V] with CHOPCONF.vsense = 0 and = 1
VFS: Final = (0.32, 0.18)


class Tmc2130Chip(Chip):
    """The TMC2130's current scaling: IRUN/IHOLD in the sense voltage range vsense."""

    def __reduce__(self) -> str:
        return "TMC2130"  # the module's constant: one chip, the same object everywhere

    @staticmethod
    def full_scale(vsense: int, sense_ohm: float) -> float:
        """The RMS current [A] of current scale 31 in range ``vsense``."""
        return VFS[vsense] / (sense_ohm + 0.02) / math.sqrt(2)

    def current_setting(self, sense_ohm: float, run_a: float, hold_a: float) -> CurrentSetting:
        check_currents(sense_ohm, run_a, hold_a)
        for vsense in (1, 0):  # the high-sensitivity range gives finer steps when it suffices
            fs = self.full_scale(vsense, sense_ohm)
            if run_a <= fs * 1.0001:
                return CurrentSetting(
                    current_scale(run_a, fs), current_scale(hold_a, fs), vsense=vsense
                )
        raise ValueError(
            f"run_current {run_a} A is above the {self.full_scale(0, sense_ohm):.2f} A a "
            f"TMC2130 gives with a {sense_ohm} ohm sense resistor"
        )

    def rms(self, setting: CurrentSetting, sense_ohm: float, cs: int) -> float:
        return (cs + 1) / 32 * self.full_scale(setting.vsense, sense_ohm)

    def scale_registers(self, setting: CurrentSetting, chopconf: int) -> dict[int, int]:
        return {Reg.CHOPCONF: F.VSENSE.put(chopconf, setting.vsense)}


TMC2130: Final = Tmc2130Chip(
    name="TMC2130",
    version=0x11,
    readable=frozenset(
        {Reg.GCONF, Reg.GSTAT, Reg.IOIN, Reg.TSTEP, Reg.MSCNT, Reg.CHOPCONF, Reg.DRV_STATUS}
    ),
    status_bits=4,
    has_ramp=False,
    default_sense_ohm=0.11,
    registers=register_names(Reg),
    shorts=SHORTS_TO_GROUND,
    flags=DRV_FLAGS,
)
