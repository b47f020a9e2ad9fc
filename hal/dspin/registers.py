"""The registers of the dSPIN chips, declared once and keyed by name (Klipper's TMC field
tables are the model): address, length in bits, reset value, when SetParam may write it, and
the bit fields motorctl reads or writes.

Sources (docs/dspin.md, "Registers"): the register map tables of the datasheets (L6470
DocID16737 Table 9/12 "Register map", L6472 DocID022729 "Register map", L6480 DocID023278
Table 11, powerSTEP01 DocID025022 "Register map") and ST's own drivers that transcribe them
(X-CUBE-SPN2 ``L6470.c``: address, bits, reset value of every L6470 register).

Pure data: any thread.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Final

from motorctl.hal.dspin.counter import ABS_POS_BITS as ABS_POS_BITS  # its length


class Access(enum.Enum):
    """When SetParam may write a register (the datasheets' "Remarks" column).

    A write outside its condition is ignored and raises NOTPERF_CMD (CMD_ERROR on the
    L6480/powerSTEP01) at the end of the last argument byte; a write to a read-only or
    nonexistent register is ignored and raises WRONG_CMD at the end of the command byte, as
    an unknown command would (L6470 9.2.3 "SetParam").
    """

    READ_ONLY = "R"
    ALWAYS = "WR"  # writable at any time
    STOPPED = "WS"  # writable only while the motor is stopped
    HIZ = "WH"  # writable only while the bridges are in high impedance

    @property
    def writable(self) -> bool:
        return self is not Access.READ_ONLY


@dataclass(frozen=True)
class Field:
    """A bit field of a register: ``width`` bits from ``shift``."""

    name: str
    shift: int
    width: int = 1

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.shift

    def get(self, word: int) -> int:
        return (word >> self.shift) & ((1 << self.width) - 1)

    def put(self, word: int, value: int) -> int:
        """``word`` with this field set to ``value``; ValueError when it does not fit."""
        if not 0 <= value < 1 << self.width:
            raise ValueError(f"{self.name}: {value} does not fit {self.width} bits")
        return (word & ~self.mask) | (value << self.shift)


@dataclass(frozen=True)
class Register:
    """One register: ``bits`` long, sent MSB first in ``nbytes`` bytes; ``reset`` is its
    value after power-up or ResetDevice (None: it depends on the conditions, as ADC_OUT's
    and STATUS's do); ``signed``: 22-bit two's complement (ABS_POS, MARK)."""

    name: str
    addr: int
    bits: int
    reset: int | None
    access: Access
    fields: tuple[Field, ...] = ()
    signed: bool = False

    @property
    def nbytes(self) -> int:
        return (self.bits + 7) // 8

    @property
    def mask(self) -> int:
        return (1 << self.bits) - 1

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no field {name}")

    def word(self, value: int) -> int:
        """The register's bits for ``value`` (a signed one in two's complement);
        ValueError when it does not fit."""
        if self.signed:
            lo, hi = -(1 << (self.bits - 1)), (1 << (self.bits - 1)) - 1
        else:
            lo, hi = 0, self.mask
        if not lo <= value <= hi:
            raise ValueError(f"{self.name}: {value} is outside {lo}..{hi} ({self.bits} bits)")
        return value & self.mask

    def value(self, word: int) -> int:
        """The register's value from its bits (sign-extended when signed); the bits above
        ``bits`` are ignored, as the chip ignores them."""
        word &= self.mask
        if self.signed and word >> (self.bits - 1):
            word -= 1 << self.bits
        return word


@dataclass(frozen=True)
class RegisterMap:
    """A chip's registers by name and by address."""

    registers: tuple[Register, ...]
    by_name: Mapping[str, Register] = field(init=False)
    by_addr: Mapping[int, Register] = field(init=False)

    def __post_init__(self) -> None:
        names = {r.name: r for r in self.registers}
        addrs = {r.addr: r for r in self.registers}
        if len(names) != len(self.registers) or len(addrs) != len(self.registers):
            raise ValueError("a register map names each register and address once")
        object.__setattr__(self, "by_name", MappingProxyType(names))
        object.__setattr__(self, "by_addr", MappingProxyType(addrs))

    def __getitem__(self, name: str) -> Register:
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(f"no register {name}") from None

    def __contains__(self, name: object) -> bool:
        return name in self.by_name

    def __iter__(self) -> Iterator[Register]:
        return iter(self.registers)

    def at(self, addr: int) -> Register | None:
        """The register at ``addr``, None where the chip has none (reserved addresses)."""
        return self.by_addr.get(addr)


R, WR, WS, WH = Access.READ_ONLY, Access.ALWAYS, Access.STOPPED, Access.HIZ


#: the registers every model has, at the same address, with the same length and reset value
_POSITION = (
    Register("ABS_POS", 0x01, ABS_POS_BITS, 0, WS, signed=True),
    Register("EL_POS", 0x02, 9, 0, WS, (Field("MICROSTEP", 0, 7), Field("STEP", 7, 2))),
    Register("MARK", 0x03, ABS_POS_BITS, 0, WR, signed=True),
    Register("SPEED", 0x04, 20, 0, R),
    Register("ACC", 0x05, 12, 0x08A, WS),
    Register("DEC", 0x06, 12, 0x08A, WS),
    Register("MAX_SPEED", 0x07, 10, 0x041, WR),
)
_MIN_SPEED = Register(
    "MIN_SPEED", 0x08, 13, 0x000, WS, (Field("MIN_SPEED", 0, 12), Field("LSPD_OPT", 12))
)
_ADC_OUT = Register("ADC_OUT", 0x12, 5, None, R)
_FS_SPD_10 = Register("FS_SPD", 0x15, 10, 0x027, WR, (Field("FS_SPD", 0, 10),))
_FS_SPD_11 = Register(
    "FS_SPD", 0x15, 11, 0x027, WR, (Field("FS_SPD", 0, 10), Field("BOOST_MODE", 10))
)
_STEP_FIELDS = (Field("STEP_SEL", 0, 3), Field("SYNC_SEL", 4, 3), Field("SYNC_EN", 7))
_STEP_MODE = Register("STEP_MODE", 0x16, 8, 0x07, WH, _STEP_FIELDS)
_STEP_MODE_CM_VM = Register("STEP_MODE", 0x16, 8, 0x07, WH, (*_STEP_FIELDS, Field("CM_VM", 3)))
#: the voltage mode's registers (L6470, L6480, powerSTEP01 in voltage mode); STALL_TH added
#: per model (7 bits on the L6470, 5 on the L6480 and powerSTEP01)
_VOLTAGE = (
    Register("KVAL_HOLD", 0x09, 8, 0x29, WR),
    Register("KVAL_RUN", 0x0A, 8, 0x29, WR),
    Register("KVAL_ACC", 0x0B, 8, 0x29, WR),
    Register("KVAL_DEC", 0x0C, 8, 0x29, WR),
    Register("INT_SPEED", 0x0D, 14, 0x0408, WH),
    Register("ST_SLP", 0x0E, 8, 0x19, WH),
    Register("FN_SLP_ACC", 0x0F, 8, 0x29, WH),
    Register("FN_SLP_DEC", 0x10, 8, 0x29, WH),
    Register("K_THERM", 0x11, 4, 0x0, WR),
)
#: the current mode's registers (L6472, powerSTEP01 in current mode), at the addresses the
#: voltage mode's KVAL_*, ST_SLP, FN_SLP_* have
_CURRENT = (
    Register("TVAL_HOLD", 0x09, 7, 0x29, WR),
    Register("TVAL_RUN", 0x0A, 7, 0x29, WR),
    Register("TVAL_ACC", 0x0B, 7, 0x29, WR),
    Register("TVAL_DEC", 0x0C, 7, 0x29, WR),
    Register("T_FAST", 0x0E, 8, 0x19, WH, (Field("FAST_STEP", 0, 4), Field("TOFF_FAST", 4, 4))),
    Register("TON_MIN", 0x0F, 7, 0x29, WH),
    Register("TOFF_MIN", 0x10, 7, 0x29, WH),
)
_COMMON_CONFIG = (
    Field("OSC_SEL", 0, 3),
    Field("EXT_CLK", 3),
    Field("SW_MODE", 4),  # 0: a switch turn-on event hard-stops the motor; 1: user disposal
    Field("OC_SD", 7),  # 1: an overcurrent turns the bridges off
)
#: ALARM_EN: bit n enables alarm n on the FLAG output (names in chips.py per model)
_ALARM_EN = Register("ALARM_EN", 0x17, 8, 0xFF, WS)

L6470_REGISTERS: Final = RegisterMap(
    (
        *_POSITION,
        _MIN_SPEED,
        *_VOLTAGE,
        _ADC_OUT,
        Register("OCD_TH", 0x13, 4, 0x8, WR),
        Register("STALL_TH", 0x14, 7, 0x40, WR),
        _FS_SPD_10,
        _STEP_MODE,
        _ALARM_EN,
        Register(
            "CONFIG",
            0x18,
            16,
            0x2E88,
            WH,
            (
                *_COMMON_CONFIG,
                Field("EN_VSCOMP", 5),
                Field("POW_SR", 8, 2),
                Field("F_PWM_DEC", 10, 3),
                Field("F_PWM_INT", 13, 3),
            ),
        ),
        Register("STATUS", 0x19, 16, None, R),
    )
)

#: The L6472 drives in current mode only: TVAL_*, T_FAST, TON_MIN, TOFF_MIN where the L6470
#: has KVAL_* and the BEMF registers; 0x0D, 0x11 and 0x14 are reserved (no INT_SPEED, no
#: K_THERM, no STALL_TH: it has no stall detection); its step mode stops at 1/16.
L6472_REGISTERS: Final = RegisterMap(
    (
        *_POSITION,
        Register("MIN_SPEED", 0x08, 13, 0x000, WS, (Field("MIN_SPEED", 0, 12),)),
        *_CURRENT,
        _ADC_OUT,
        Register("OCD_TH", 0x13, 4, 0x8, WR),
        _FS_SPD_10,
        _STEP_MODE,
        _ALARM_EN,
        Register(
            "CONFIG",
            0x18,
            16,
            0x2E88,
            WH,
            (*_COMMON_CONFIG, Field("EN_TQREG", 5), Field("POW_SR", 8, 2), Field("TSW", 10, 5)),
        ),
        Register("STATUS", 0x19, 16, None, R),
    )
)

#: What the L6480 and the powerSTEP01 share beyond the position registers: 5-bit OCD_TH and
#: STALL_TH, the 11-bit FS_SPD with BOOST_MODE, the gate driver's GATECFG1/GATECFG2 at
#: 0x18/0x19, which pushes CONFIG to 0x1A and STATUS to 0x1B.
_L6480_TAIL = (
    _ADC_OUT,
    Register("OCD_TH", 0x13, 5, 0x08, WR),
    Register("STALL_TH", 0x14, 5, 0x10, WR),
    _FS_SPD_11,
    _ALARM_EN,
    Register(
        "GATECFG1",
        0x18,
        11,
        0x000,
        WH,
        (Field("TCC", 0, 5), Field("IGATE", 5, 3), Field("TBOOST", 8, 3)),
    ),
    Register("GATECFG2", 0x19, 8, 0x00, WH, (Field("TDT", 0, 5), Field("TBLANK", 5, 3))),
    Register("STATUS", 0x1B, 16, None, R),
)
_L6480_CONFIG_VOLTAGE = Register(
    "CONFIG",
    0x1A,
    16,
    0x2C88,
    WH,
    (
        *_COMMON_CONFIG,
        Field("EN_VSCOMP", 5),
        Field("UVLOVAL", 8),
        Field("VCCVAL", 9),
        Field("F_PWM_DEC", 10, 3),
        Field("F_PWM_INT", 13, 3),
    ),
)

L6480_REGISTERS: Final = RegisterMap(
    (*_POSITION, _MIN_SPEED, *_VOLTAGE, _STEP_MODE, _L6480_CONFIG_VOLTAGE, *_L6480_TAIL)
)

#: The powerSTEP01 is an L6480 with its MOSFETs in the package and a current mode: STEP_MODE
#: bit 3 (CM_VM) selects it, and then 0x09..0x10 are TVAL_*, T_FAST, TON_MIN, TOFF_MIN and
#: CONFIG's upper bits are the current control's (EN_TQREG, TSW, PRED_EN). INT_SPEED,
#: K_THERM and STALL_TH stay at their addresses in both modes.
POWERSTEP01_VOLTAGE_REGISTERS: Final = RegisterMap(
    (
        *_POSITION,
        _MIN_SPEED,
        *_VOLTAGE,
        _STEP_MODE_CM_VM,
        _L6480_CONFIG_VOLTAGE,
        *_L6480_TAIL,
    )
)
POWERSTEP01_CURRENT_REGISTERS: Final = RegisterMap(
    (
        *_POSITION,
        _MIN_SPEED,
        *_CURRENT,
        Register("INT_SPEED", 0x0D, 14, 0x0408, WH),
        Register("K_THERM", 0x11, 4, 0x0, WR),
        _STEP_MODE_CM_VM,
        Register(
            "CONFIG",
            0x1A,
            16,
            0x2C88,
            WH,
            (
                *_COMMON_CONFIG,
                Field("EN_TQREG", 5),
                Field("UVLOVAL", 8),
                Field("VCCVAL", 9),
                Field("TSW", 10, 5),
                Field("PRED_EN", 15),
            ),
        ),
        *_L6480_TAIL,
    )
)
