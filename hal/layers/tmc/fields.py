"""What the TMC chips share: bit fields keyed by their register, what a chip is, the
registers and fields both chips have, the SPI status byte and a few formulas of both
datasheets (TMC2130 rev. 1.15, TMC5160 rev. 1.14).

As Klipper keeps its tmc.py under one module per chip, the chip modules (``tmc2130.py``,
``tmc5160.py``) each hold one chip's whole driver: its own registers and fields, its
:class:`Chip` (what the shared driver asks of it: its current scaling, its status flags, its
registers by name) and, for the TMC5160, the driver class of its ramp generator. This module
imports none of them: what differs between the chips is asked of the :class:`Chip`.

Pure data and functions: no state, no I/O; any thread.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True)
class Field:
    """A bit field of register ``reg``: ``width`` bits from ``shift``; ``signed`` = two's
    complement."""

    reg: int
    shift: int
    width: int = 1
    signed: bool = False

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.shift

    def get(self, value: int) -> int:
        """The field's value in ``value``, a word of its register."""
        v = (value >> self.shift) & ((1 << self.width) - 1)
        if self.signed and v >> (self.width - 1):
            v -= 1 << self.width
        return v

    def put(self, value: int, field: int) -> int:
        """``value`` (a word of its register) with this field set to ``field``."""
        lo = -(1 << (self.width - 1)) if self.signed else 0
        hi = (1 << (self.width - 1)) - 1 if self.signed else (1 << self.width) - 1
        if not lo <= field <= hi:
            raise ValueError(f"{field} does not fit a {self.width}-bit field")
        return (value & ~self.mask) | ((field << self.shift) & self.mask)


@dataclass(frozen=True)
class CurrentSetting:
    """IRUN/IHOLD current scales and the range they are in (a chip's own: the TMC2130's
    CHOPCONF.vsense, the TMC5160's GLOBALSCALER)."""

    irun: int
    ihold: int
    vsense: int = 0  # TMC2130
    globalscaler: int = 0  # TMC5160: register value, 0 means 256


@dataclass(frozen=True, eq=False)
class Chip(ABC):
    """One kind of chip: what the shared driver (``driver.py``), the SPI link and the
    settings ask of it. One instance per chip module (``tmc2130.TMC2130``,
    ``tmc5160.TMC5160``), compared by identity and pickled as that module's constant.

    ``shorts``: its DRV_STATUS flags of a shorted bridge (they disable the driver), with
    their words; ``flags``: every DRV_STATUS flag ``--probe`` names, in its order;
    ``registers``: address -> name of every register it has (messages); ``sd_mode``:
    IOIN's SD_MODE pin where it has one (1: external STEP/DIR); ``gstat_write_clears``:
    GSTAT's flags clear by writing 1s back (else by reading); ``uv_cp``: GSTAT.uv_cp
    (charge pump undervoltage) is one of its flags.
    """

    name: str
    version: int  # IOIN.VERSION
    readable: frozenset[int]
    status_bits: int  # how many SPI status bits it defines
    has_ramp: bool
    default_sense_ohm: float
    registers: Mapping[int, str]
    shorts: tuple[tuple[Field, str], ...]
    flags: tuple[tuple[str, Field], ...]
    sd_mode: Field | None = None
    gstat_write_clears: bool = False
    uv_cp: bool = False

    @abstractmethod
    def current_setting(self, sense_ohm: float, run_a: float, hold_a: float) -> CurrentSetting:
        """IRUN/IHOLD and the chip's range for RMS currents; ValueError when impossible."""

    @abstractmethod
    def rms(self, setting: CurrentSetting, sense_ohm: float, cs: int) -> float:
        """The RMS coil current [A] that current scale ``cs`` gives (datasheet formula)."""

    @abstractmethod
    def scale_registers(self, setting: CurrentSetting, chopconf: int) -> dict[int, int]:
        """Where the chip keeps its current range: CHOPCONF (``chopconf`` with it set) and
        any register of its own, in the order they are written after GCONF."""

    def register_name(self, addr: int) -> str:
        return self.registers.get(addr, f"register 0x{addr:02x}")


def check_currents(sense_ohm: float, run_a: float, hold_a: float) -> None:
    """What every chip's current scaling needs; ValueError naming what is wrong."""
    if sense_ohm <= 0:
        raise ValueError("sense_resistor must be > 0")
    if run_a <= 0 or hold_a < 0 or hold_a > run_a:
        raise ValueError("currents must satisfy 0 <= hold_current <= run_current, run > 0")


def current_scale(current: float, full_scale: float) -> int:
    """The 5-bit current scale (IRUN, IHOLD) nearest to ``current`` of ``full_scale``."""
    return max(0, min(31, round(32 * current / full_scale) - 1))


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


def register_names(regs: type) -> dict[int, str]:
    """Address -> name of a ``Reg`` class's registers (its own and inherited)."""
    return {
        getattr(regs, name): name
        for name in dir(regs)
        if not name.startswith("_") and isinstance(getattr(regs, name), int)
    }


class F:
    """The fields motorctl sets or reads that both chips have, each keyed by its register
    (a chip module's ``F`` adds its own)."""

    EN_PWM_MODE: Final = Field(Reg.GCONF, 2)
    SHAFT: Final = Field(Reg.GCONF, 4)
    DIAG1_STALL: Final = Field(Reg.GCONF, 8)  # TMC2130 diag1_stall / TMC5160 diag1_stall_dir
    RESET: Final = Field(Reg.GSTAT, 0)
    DRV_ERR: Final = Field(Reg.GSTAT, 1)
    UV_CP: Final = Field(Reg.GSTAT, 2)
    VERSION: Final = Field(Reg.IOIN, 24, 8)
    IHOLD: Final = Field(Reg.IHOLD_IRUN, 0, 5)
    IRUN: Final = Field(Reg.IHOLD_IRUN, 8, 5)
    IHOLDDELAY: Final = Field(Reg.IHOLD_IRUN, 16, 4)
    TOFF: Final = Field(Reg.CHOPCONF, 0, 4)
    HSTRT: Final = Field(Reg.CHOPCONF, 4, 3)
    HEND: Final = Field(Reg.CHOPCONF, 7, 4)
    TBL: Final = Field(Reg.CHOPCONF, 15, 2)
    MRES: Final = Field(Reg.CHOPCONF, 24, 4)
    INTPOL: Final = Field(Reg.CHOPCONF, 28)
    SGT: Final = Field(Reg.COOLCONF, 16, 7, signed=True)
    SFILT: Final = Field(Reg.COOLCONF, 24)
    SG_RESULT: Final = Field(Reg.DRV_STATUS, 0, 10)
    FSACTIVE: Final = Field(Reg.DRV_STATUS, 15)
    CS_ACTUAL: Final = Field(Reg.DRV_STATUS, 16, 5)
    STALLGUARD: Final = Field(Reg.DRV_STATUS, 24)
    OT: Final = Field(Reg.DRV_STATUS, 25)
    OTPW: Final = Field(Reg.DRV_STATUS, 26)
    S2GA: Final = Field(Reg.DRV_STATUS, 27)
    S2GB: Final = Field(Reg.DRV_STATUS, 28)
    OLA: Final = Field(Reg.DRV_STATUS, 29)
    OLB: Final = Field(Reg.DRV_STATUS, 30)
    STST: Final = Field(Reg.DRV_STATUS, 31)


#: DRV_STATUS: the shorts to ground both chips flag, and the flags both have, as --probe
#: names them
SHORTS_TO_GROUND: Final = (
    (F.S2GA, "short to ground on phase A (s2ga)"),
    (F.S2GB, "short to ground on phase B (s2gb)"),
)
DRV_FLAGS: Final = (
    ("stst", F.STST),
    ("olb", F.OLB),
    ("ola", F.OLA),
    ("s2gb", F.S2GB),
    ("s2ga", F.S2GA),
    ("otpw", F.OTPW),
    ("ot", F.OT),
    ("stallGuard", F.STALLGUARD),
    ("fsactive", F.FSACTIVE),
)

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
