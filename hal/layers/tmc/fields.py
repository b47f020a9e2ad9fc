"""The TMC chips' shared helpers: bit fields, what a chip is, the registers both chips have.

As Klipper keeps one module per chip over its tmc.py, the chip modules (``tmc2130.py``,
``tmc5160.py``) hold each chip's own registers, fields and constants as data; this module
holds what they share: :class:`Field` (a register's bit field), :class:`Chip` (what differs
between the chips), the register addresses (:class:`Reg`) and fields (:class:`F`) that both
chips have at the same place, the SPI status byte and a few formulas of both datasheets
(TMC2130 rev. 1.15, TMC5160 rev. 1.14).

Pure data and functions: no state, no I/O; any thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True)
class Field:
    """A bit field of a register: ``width`` bits from ``shift``; ``signed`` = two's complement."""

    shift: int
    width: int = 1
    signed: bool = False

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.shift

    def get(self, reg: int) -> int:
        v = (reg >> self.shift) & ((1 << self.width) - 1)
        if self.signed and v >> (self.width - 1):
            v -= 1 << self.width
        return v

    def put(self, reg: int, value: int) -> int:
        lo = -(1 << (self.width - 1)) if self.signed else 0
        hi = (1 << (self.width - 1)) - 1 if self.signed else (1 << self.width) - 1
        if not lo <= value <= hi:
            raise ValueError(f"{value} does not fit a {self.width}-bit field")
        return (reg & ~self.mask) | ((value << self.shift) & self.mask)


@dataclass(frozen=True)
class Chip:
    """What differs between the chips: version, readable registers, current scaling."""

    name: str
    version: int
    readable: frozenset[int]
    status_bits: int  # how many SPI status bits it defines
    has_ramp: bool
    has_s2vs: bool
    default_sense_ohm: float


class Reg:
    """Register addresses both chips have (a chip module's ``Reg`` adds its own)."""

    GCONF: Final = 0x00
    GSTAT: Final = 0x01
    IOIN: Final = 0x04
    IHOLD_IRUN: Final = 0x10
    TPOWERDOWN: Final = 0x11
    TSTEP: Final = 0x12
    TPWMTHRS: Final = 0x13
    TCOOLTHRS: Final = 0x14
    THIGH: Final = 0x15
    MSCNT: Final = 0x6A
    CHOPCONF: Final = 0x6C
    COOLCONF: Final = 0x6D
    DRV_STATUS: Final = 0x6F
    PWMCONF: Final = 0x70


class F:
    """The fields motorctl sets or reads that both chips have (a chip module's ``F`` adds
    its own)."""

    # GCONF
    EN_PWM_MODE: Final = Field(2)
    SHAFT: Final = Field(4)
    DIAG1_STALL: Final = Field(8)  # TMC2130 diag1_stall / TMC5160 diag1_stall_dir
    # GSTAT
    RESET: Final = Field(0)
    DRV_ERR: Final = Field(1)
    UV_CP: Final = Field(2)
    # IOIN
    VERSION: Final = Field(24, 8)
    # IHOLD_IRUN
    IHOLD: Final = Field(0, 5)
    IRUN: Final = Field(8, 5)
    IHOLDDELAY: Final = Field(16, 4)
    # CHOPCONF
    TOFF: Final = Field(0, 4)
    HSTRT: Final = Field(4, 3)
    HEND: Final = Field(7, 4)
    TBL: Final = Field(15, 2)
    MRES: Final = Field(24, 4)
    INTPOL: Final = Field(28)
    # COOLCONF
    SGT: Final = Field(16, 7, signed=True)
    SFILT: Final = Field(24)
    # DRV_STATUS
    SG_RESULT: Final = Field(0, 10)
    FSACTIVE: Final = Field(15)
    CS_ACTUAL: Final = Field(16, 5)
    STALLGUARD: Final = Field(24)
    OT: Final = Field(25)
    OTPW: Final = Field(26)
    S2GA: Final = Field(27)
    S2GB: Final = Field(28)
    OLA: Final = Field(29)
    OLB: Final = Field(30)
    STST: Final = Field(31)


#: SPI status byte, bit -> name (bits 4..7 exist on the TMC5160 only)
SPI_STATUS_BITS: Final = (
    "reset_flag",
    "driver_error",
    "sg2",
    "standstill",
    "velocity_reached",
    "position_reached",
    "status_stop_l",
    "status_stop_r",
)


def decode_spi_status(byte: int, chip: Chip) -> list[str]:
    """The names of the SPI status bits set in ``byte`` that ``chip`` defines."""
    return [n for i, n in enumerate(SPI_STATUS_BITS[: chip.status_bits]) if byte >> i & 1]


def signed32(v: int) -> int:
    """A 32-bit register's two's complement value."""
    return v - (1 << 32) if v & (1 << 31) else v


def mres_of(microsteps: int) -> int:
    """CHOPCONF.MRES for ``microsteps`` per full step (256 -> 0, ..., 1 -> 8)."""
    if microsteps < 1 or microsteps > 256 or microsteps & (microsteps - 1):
        raise ValueError(f"microsteps must be a power of two from 1 to 256, not {microsteps}")
    return 8 - int(math.log2(microsteps))


def tstep_for(speed: float, microsteps: int, clock_hz: float) -> int:
    """TSTEP (clocks between 1/256 microsteps, 20 bits) at ``speed`` steps/s; 0 speed -> 0."""
    if speed <= 0:
        return 0
    per_256 = speed * (256 / microsteps)
    return max(1, min((1 << 20) - 1, int(clock_hz / per_256)))
