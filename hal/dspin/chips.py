"""The dSPIN chips: a model in a mode, with its registers, its STATUS layout, its ALARM_EN
bits and its step modes.

| chip | mode | CONFIG | STATUS | microsteps | stall detection |
|---|---|---|---|---|---|
| L6470 | voltage | 0x18, reset 0x2E88 | 0x19, L6470 layout | up to 1/128 | STEP_LOSS_A/B |
| L6472 | current | 0x18, reset 0x2E88 | 0x19, no stall bits | up to 1/16 | none |
| L6480 | voltage | 0x1A, reset 0x2C88 | 0x1B, L6480 layout | up to 1/128 | STEP_LOSS_A/B |
| powerSTEP01 | voltage | 0x1A, reset 0x2C88 | 0x1B, L6480 layout | up to 1/128 | STEP_LOSS_A/B |
| powerSTEP01 | current | 0x1A, reset 0x2C88 | 0x1B, L6480 layout | up to 1/16 | STEP_LOSS_A/B |

STEP_SEL (STEP_MODE bits 0..2) selects 1 << STEP_SEL microsteps; where the chip stops at
1/16 (the L6472, the powerSTEP01 in current mode) the values 4..7 all mean 1/16. The
powerSTEP01's mode is STEP_MODE.CM_VM (bit 3, 1 = current mode), writable in HiZ only as
STEP_MODE is; the L6470/L6472/L6480 have no such bit.

Pure data: any thread.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

from motorctl.hal.dspin.registers import (
    L6470_REGISTERS,
    L6472_REGISTERS,
    L6480_REGISTERS,
    POWERSTEP01_CURRENT_REGISTERS,
    POWERSTEP01_VOLTAGE_REGISTERS,
    Register,
    RegisterMap,
)
from motorctl.hal.dspin.status import L6470_STATUS, L6472_STATUS, L6480_STATUS, StatusLayout


class Mode(enum.Enum):
    VOLTAGE = "voltage"
    CURRENT = "current"


#: ALARM_EN bit n -> the alarm it enables on FLAG (None: unused), per family
L6470_ALARMS: Final = (
    "OCD",
    "TH_SD",
    "TH_WRN",
    "UVLO",
    "STEP_LOSS_A",
    "STEP_LOSS_B",
    "SW_EVN",
    "WRONG_CMD/NOTPERF_CMD",
)
L6472_ALARMS: Final = (*L6470_ALARMS[:4], None, None, *L6470_ALARMS[6:])
L6480_ALARMS: Final = (
    "OCD",
    "TH_SHUTDOWN",
    "TH_WARNING",
    "UVLO",
    "UVLO_ADC",
    "STEP_LOSS",
    "SW_EVN",
    "CMD_ERROR",
)


@dataclass(frozen=True, eq=False)
class Chip:
    """One chip in one mode; compared by identity (one object per kind, in ``CHIPS``)."""

    model: str
    mode: Mode
    registers: RegisterMap
    status: StatusLayout
    alarms: tuple[str | None, ...]
    max_microsteps: int

    @property
    def name(self) -> str:
        """``L6470``; ``powerSTEP01 (current mode)`` where a model has two modes."""
        if self.model == "powerSTEP01":
            return f"{self.model} ({self.mode.value} mode)"
        return self.model

    @property
    def key(self) -> str:
        """The chip's name in a config: ``l6470``, ``powerstep01-current``..."""
        return self.model.lower() + ("-current" if self is POWERSTEP01_CURRENT else "")

    @property
    def config(self) -> Register:
        return self.registers["CONFIG"]

    @property
    def status_register(self) -> Register:
        return self.registers["STATUS"]

    @property
    def has_stall_detection(self) -> bool:
        return self.status.by_name.get("STEP_LOSS_A") is not None

    def microsteps(self, step_sel: int) -> int:
        """Microsteps per full step for STEP_MODE.STEP_SEL ``step_sel`` (0..7)."""
        if not 0 <= step_sel <= 7:
            raise ValueError(f"STEP_SEL is 3 bits, not {step_sel}")
        return min(1 << step_sel, self.max_microsteps)

    def step_sel(self, microsteps: int) -> int:
        """STEP_SEL for ``microsteps`` per full step; ValueError naming what the chip can."""
        for sel in range(8):
            if 1 << sel == microsteps and microsteps <= self.max_microsteps:
                return sel
        raise ValueError(
            f"the {self.name} cannot do {microsteps} microsteps per step: it does 1, 2, 4, "
            f"... {self.max_microsteps}"
        )

    def step_mode(self, microsteps: int) -> int:
        """STEP_MODE for ``microsteps``: STEP_SEL, SYNC_EN 0 (BUSY on the BUSY/SYNC pin),
        and on a powerSTEP01 CM_VM for its mode."""
        word = self.step_sel(microsteps)
        if self.model == "powerSTEP01" and self.mode is Mode.CURRENT:
            word = self.registers["STEP_MODE"].field("CM_VM").put(word, 1)
        return word


L6470: Final = Chip("L6470", Mode.VOLTAGE, L6470_REGISTERS, L6470_STATUS, L6470_ALARMS, 128)
L6472: Final = Chip("L6472", Mode.CURRENT, L6472_REGISTERS, L6472_STATUS, L6472_ALARMS, 16)
L6480: Final = Chip("L6480", Mode.VOLTAGE, L6480_REGISTERS, L6480_STATUS, L6480_ALARMS, 128)
POWERSTEP01_VOLTAGE: Final = Chip(
    "powerSTEP01",
    Mode.VOLTAGE,
    POWERSTEP01_VOLTAGE_REGISTERS,
    L6480_STATUS,
    L6480_ALARMS,
    128,
)
POWERSTEP01_CURRENT: Final = Chip(
    "powerSTEP01",
    Mode.CURRENT,
    POWERSTEP01_CURRENT_REGISTERS,
    L6480_STATUS,
    L6480_ALARMS,
    16,
)

#: every chip by its config name
CHIPS: Final = {c.key: c for c in (L6470, L6472, L6480, POWERSTEP01_VOLTAGE, POWERSTEP01_CURRENT)}
