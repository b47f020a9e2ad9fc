"""The STATUS register of each dSPIN model, bit by bit, and its decoding into named flags.

The L6470 and the L6472 share one layout (the L6472 leaves bits 13 and 14 unused: it has no
stall detection); the L6480 and the powerSTEP01 share another: one CMD_ERROR where the
L6470 has NOTPERF_CMD and WRONG_CMD, STCK_MOD moved to bit 8, an ADC undervoltage flag, a
two-bit TH_STATUS where the L6470 has TH_WRN and TH_SD, and OCD, STEP_LOSS_A, STEP_LOSS_B
one bit higher. Sources (docs/dspin.md, "STATUS"): L6470 9.1.22 Table 36, L6480 9.1.24,
powerSTEP01 11.1.28; ST's drivers (X-CUBE-SPN2 ``L6470.h``, the cSPIN L6480 library,
X-CUBE-SPN3 ``powerstep01.h``) give the same masks.

Which flags are active low (0 = the condition): BUSY (0 = busy), UVLO, UVLO_ADC, TH_WRN,
TH_SD, OCD, STEP_LOSS_A, STEP_LOSS_B. Which are latched until a GetStatus command (and
then only if the condition has gone): SW_EVN, the command errors, UVLO, UVLO_ADC, TH_WRN,
TH_SD, TH_STATUS, OCD, STEP_LOSS_A/B. Reading STATUS with GetParam clears nothing.

Pure data and functions: any thread.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType
from typing import Final


class Kind(enum.Enum):
    """What a flag tells."""

    STATE = "state"  # what the chip is doing (HiZ, BUSY, DIR, MOT_STATUS, SW_F, step clock)
    EVENT = "event"  # something happened that the host should see (SW_EVN)
    COMMAND = "command"  # the chip refused a command (WRONG_CMD, NOTPERF_CMD, CMD_ERROR)
    WARNING = "warning"  # a condition that does not stop the motor (TH_WRN)
    FAULT = "fault"  # a condition that stops the motor or makes its position doubtful


@dataclass(frozen=True)
class Flag:
    """One flag (or field) of STATUS: ``width`` bits from ``bit``; ``active_low``: the
    condition reads 0; ``latched``: held until GetStatus once the condition has gone."""

    name: str
    bit: int
    kind: Kind
    width: int = 1
    active_low: bool = False
    latched: bool = False

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.bit

    def raw(self, word: int) -> int:
        return (word >> self.bit) & ((1 << self.width) - 1)

    def level(self, word: int) -> int:
        """The flag's value with active-low flags turned round: nonzero = the condition."""
        raw = self.raw(word)
        return raw ^ 1 if self.active_low and self.width == 1 else raw


class MotorState(enum.IntEnum):
    """MOT_STATUS."""

    STOPPED = 0
    ACCELERATION = 1
    DECELERATION = 2
    CONSTANT_SPEED = 3


class ThermalState(enum.IntEnum):
    """TH_STATUS of the L6480 and powerSTEP01."""

    NORMAL = 0
    WARNING = 1
    BRIDGE_SHUTDOWN = 2
    DEVICE_SHUTDOWN = 3


S, E, C, W, F = Kind.STATE, Kind.EVENT, Kind.COMMAND, Kind.WARNING, Kind.FAULT


@dataclass(frozen=True)
class StatusLayout:
    """The flags of one STATUS layout by name; ``unused``: bits no flag covers."""

    name: str
    flags: tuple[Flag, ...]

    @cached_property
    def by_name(self) -> Mapping[str, Flag]:
        """Built once per layout (every STATUS decode and the mock's chips look flags up)."""
        return MappingProxyType({f.name: f for f in self.flags})

    @property
    def unused(self) -> int:
        used = 0
        for f in self.flags:
            used |= f.mask
        return 0xFFFF & ~used

    @property
    def latched_mask(self) -> int:
        """The bits GetStatus may clear."""
        mask = 0
        for f in self.flags:
            if f.latched:
                mask |= f.mask
        return mask

    @property
    def idle_word(self) -> int:
        """STATUS with no condition at all: every active-low flag high, the rest 0."""
        word = 0
        for f in self.flags:
            if f.active_low:
                word |= f.mask
        return word

    def __getitem__(self, name: str) -> Flag:
        return self.by_name[name]

    def decode(self, word: int) -> Status:
        return Status(self, word & 0xFFFF)


_HEAD = (
    Flag("HiZ", 0, S),
    Flag("BUSY", 1, S, active_low=True),
    Flag("SW_F", 2, S),  # 1: the switch is closed (SW input low)
    Flag("SW_EVN", 3, E, latched=True),  # a switch turn-on event (SW's falling edge)
    Flag("DIR", 4, S),  # 1: forward
    Flag("MOT_STATUS", 5, S, width=2),
)

L6470_STATUS: Final = StatusLayout(
    "L6470",
    (
        *_HEAD,
        Flag("NOTPERF_CMD", 7, C, latched=True),
        Flag("WRONG_CMD", 8, C, latched=True),
        Flag("UVLO", 9, F, active_low=True, latched=True),
        Flag("TH_WRN", 10, W, active_low=True, latched=True),
        Flag("TH_SD", 11, F, active_low=True, latched=True),
        Flag("OCD", 12, F, active_low=True, latched=True),
        Flag("STEP_LOSS_A", 13, F, active_low=True, latched=True),
        Flag("STEP_LOSS_B", 14, F, active_low=True, latched=True),
        Flag("SCK_MOD", 15, S),
    ),
)

#: the L6470's layout without the stall flags (bits 13 and 14 unused)
L6472_STATUS: Final = StatusLayout(
    "L6472", tuple(f for f in L6470_STATUS.flags if not f.name.startswith("STEP_LOSS"))
)

L6480_STATUS: Final = StatusLayout(
    "L6480",
    (
        *_HEAD,
        Flag("CMD_ERROR", 7, C, latched=True),  # NOTPERF_CMD or WRONG_CMD of the L6470
        Flag("STCK_MOD", 8, S),
        Flag("UVLO", 9, F, active_low=True, latched=True),
        Flag("UVLO_ADC", 10, F, active_low=True, latched=True),
        Flag("TH_STATUS", 11, F, width=2, latched=True),  # ThermalState; 1 is a warning
        Flag("OCD", 13, F, active_low=True, latched=True),
        Flag("STEP_LOSS_A", 14, F, active_low=True, latched=True),
        Flag("STEP_LOSS_B", 15, F, active_low=True, latched=True),
    ),
)


@dataclass(frozen=True)
class Status:
    """One STATUS word of a chip, decoded by its layout."""

    layout: StatusLayout
    word: int

    def __getitem__(self, name: str) -> int:
        """The level of flag ``name`` (nonzero = its condition; active-low turned round)."""
        return self.layout[name].level(self.word)

    def has(self, name: str) -> bool:
        return name in self.layout.by_name

    @property
    def flags(self) -> dict[str, int]:
        """Every flag by its datasheet name, as levels (1 = the condition)."""
        return {f.name: f.level(self.word) for f in self.layout.flags}

    @property
    def hiz(self) -> bool:
        return bool(self["HiZ"])

    @property
    def busy(self) -> bool:
        return bool(self["BUSY"])

    @property
    def switch_closed(self) -> bool:
        return bool(self["SW_F"])

    @property
    def switch_event(self) -> bool:
        return bool(self["SW_EVN"])

    @property
    def forward(self) -> bool:
        return bool(self["DIR"])

    @property
    def motor(self) -> MotorState:
        return MotorState(self["MOT_STATUS"])

    @property
    def thermal(self) -> ThermalState:
        """TH_STATUS, or the L6470/L6472's TH_SD and TH_WRN put the same way."""
        if self.has("TH_STATUS"):
            return ThermalState(self["TH_STATUS"])
        if self["TH_SD"]:
            return ThermalState.BRIDGE_SHUTDOWN
        return ThermalState.WARNING if self["TH_WRN"] else ThermalState.NORMAL

    def active(self, *kinds: Kind) -> tuple[str, ...]:
        """The names of the flags of ``kinds`` whose condition is present, in bit order;
        TH_STATUS is named with its state (``TH_STATUS=WARNING``)."""
        names = []
        for f in self.layout.flags:
            if f.kind not in kinds or not f.level(self.word):
                continue
            if f.name == "TH_STATUS":
                state = ThermalState(f.level(self.word))
                if state is ThermalState.WARNING and Kind.WARNING not in kinds:
                    continue  # TH_STATUS=01 is a warning, not a fault
                names.append(f"TH_STATUS={state.name}")
            else:
                names.append(f.name)
        return tuple(names)

    @property
    def faults(self) -> tuple[str, ...]:
        """The faults present: what stops the motor or makes its position doubtful."""
        return self.active(Kind.FAULT)

    @property
    def warnings(self) -> tuple[str, ...]:
        """Thermal warnings (TH_WRN, TH_STATUS=WARNING): worth a journal line, no E4."""
        return tuple(
            n for n in self.active(Kind.FAULT, Kind.WARNING) if n in ("TH_WRN", "TH_STATUS=WARNING")
        )

    @property
    def command_errors(self) -> tuple[str, ...]:
        """The chip refused a command since the last GetStatus (WRONG_CMD, NOTPERF_CMD or
        CMD_ERROR)."""
        return self.active(Kind.COMMAND)

    def __str__(self) -> str:
        parts = [f"0x{self.word:04X}", self.motor.name]
        if self.hiz:
            parts.append("HiZ")
        if self.busy:
            parts.append("BUSY")
        if self.switch_closed:
            parts.append("SW_F")
        parts += self.active(Kind.EVENT, Kind.COMMAND, Kind.WARNING, Kind.FAULT)
        return " ".join(parts)
