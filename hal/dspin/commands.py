"""The dSPIN command set and its bytes, both ways (L6470 9.2 "Application commands", Table
37 and the command structure tables after it; the same codes on every model).

Every command is one byte, some followed by an argument of 1 to 3 bytes, MSB first; the chip
answers 0x00 to every byte except the bytes after GetParam and GetStatus, which carry the
register, MSB first (9.2.1 "Command management"):

| command | byte | argument | answer |
|---|---|---|---|
| NOP | 0000 0000 | | |
| SetParam(PARAM, VALUE) | 000P PPPP | VALUE: the register's length, 1-3 bytes | |
| GetParam(PARAM) | 001P PPPP | | the register, 1-3 bytes |
| Run(DIR, SPD) | 0101 000D | SPD: 20 bits in 3 bytes | |
| StepClock(DIR) | 0101 100D | | |
| Move(DIR, N_STEP) | 0100 000D | N_STEP: 22 bits in 3 bytes | |
| GoTo(ABS_POS) | 0110 0000 | ABS_POS: 22 bits in 3 bytes | |
| GoTo_DIR(DIR, ABS_POS) | 0110 100D | ABS_POS: 22 bits in 3 bytes | |
| GoUntil(ACT, DIR, SPD) | 100A 001D | SPD: 20 bits in 3 bytes | |
| ReleaseSW(ACT, DIR) | 100A 101D | | |
| GoHome | 0111 0000 | | |
| GoMark | 0111 1000 | | |
| ResetPos | 1101 1000 | | |
| ResetDevice | 1100 0000 | | |
| SoftStop | 1011 0000 | | |
| HardStop | 1011 1000 | | |
| SoftHiZ | 1010 0000 | | |
| HardHiZ | 1010 1000 | | |
| GetStatus | 1101 0000 | | STATUS, 2 bytes |

DIR 1 = forward (ABS_POS counts up), 0 = reverse. ACT 0 = reset ABS_POS, 1 = copy ABS_POS
into MARK. Pure: any thread.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

from motorctl.hal.dspin.chips import Chip
from motorctl.hal.dspin.registers import ABS_POS_BITS, Register

NOP: Final = 0x00
FORWARD: Final = 1
REVERSE: Final = 0
RESET_ABS_POS: Final = 0  # ACT of GoUntil/ReleaseSW
COPY_TO_MARK: Final = 1
SPD_BITS: Final = 20
N_STEP_MAX: Final = (1 << ABS_POS_BITS) - 1


class Op(enum.StrEnum):
    """A command, by its datasheet name; its byte (DIR, ACT, PARAM zero) is ``CODE[op]``."""

    NOP = "NOP"
    SET_PARAM = "SetParam"
    GET_PARAM = "GetParam"
    RUN = "Run"
    STEP_CLOCK = "StepClock"
    MOVE = "Move"
    GO_TO = "GoTo"
    GO_TO_DIR = "GoTo_DIR"
    GO_UNTIL = "GoUntil"
    RELEASE_SW = "ReleaseSW"
    GO_HOME = "GoHome"
    GO_MARK = "GoMark"
    RESET_POS = "ResetPos"
    RESET_DEVICE = "ResetDevice"
    SOFT_STOP = "SoftStop"
    HARD_STOP = "HardStop"
    SOFT_HIZ = "SoftHiZ"
    HARD_HIZ = "HardHiZ"
    GET_STATUS = "GetStatus"


CODE: Final = {
    Op.NOP: 0x00,
    Op.SET_PARAM: 0x00,
    Op.GET_PARAM: 0x20,
    Op.RUN: 0x50,
    Op.STEP_CLOCK: 0x58,
    Op.MOVE: 0x40,
    Op.GO_TO: 0x60,
    Op.GO_TO_DIR: 0x68,
    Op.GO_UNTIL: 0x82,
    Op.RELEASE_SW: 0x92,
    Op.GO_HOME: 0x70,
    Op.GO_MARK: 0x78,
    Op.RESET_POS: 0xD8,
    Op.RESET_DEVICE: 0xC0,
    Op.SOFT_STOP: 0xB0,
    Op.HARD_STOP: 0xB8,
    Op.SOFT_HIZ: 0xA0,
    Op.HARD_HIZ: 0xA8,
    Op.GET_STATUS: 0xD0,
}
#: the commands with a DIR bit (bit 0), and those with an ACT bit (bit 3) too
_TAKES_DIR = (Op.RUN, Op.STEP_CLOCK, Op.MOVE, Op.GO_TO_DIR, Op.GO_UNTIL, Op.RELEASE_SW)
_TAKES_ACT = (Op.GO_UNTIL, Op.RELEASE_SW)
#: commands whose argument is 3 bytes, and how many bits of it count
_ARG_BITS = {
    Op.RUN: SPD_BITS,
    Op.GO_UNTIL: SPD_BITS,
    Op.MOVE: ABS_POS_BITS,
    Op.GO_TO: ABS_POS_BITS,
    Op.GO_TO_DIR: ABS_POS_BITS,
}
#: commands of one byte without DIR or ACT, by their byte
_PLAIN = {
    CODE[op]: op
    for op in (
        Op.GO_HOME,
        Op.GO_MARK,
        Op.RESET_POS,
        Op.RESET_DEVICE,
        Op.SOFT_STOP,
        Op.HARD_STOP,
        Op.SOFT_HIZ,
        Op.HARD_HIZ,
        Op.GET_STATUS,
    )
}


@dataclass(frozen=True)
class Command:
    """One command: ``op`` with its DIR, ACT, register (SetParam, GetParam) and value
    (SetParam's VALUE, SPD, N_STEP, ABS_POS; positions signed)."""

    op: Op
    dir: int = 0
    act: int = 0
    register: Register | None = None
    value: int = 0

    @property
    def name(self) -> str:
        if self.op in (Op.SET_PARAM, Op.GET_PARAM):
            return f"{self.op.value}({self.register.name if self.register else '?'})"
        return self.op.value

    def encode(self) -> bytes:
        """The command's bytes, MSB first; ValueError for a value out of its range."""
        head = CODE[self.op]
        if self.op in (Op.SET_PARAM, Op.GET_PARAM):
            reg = self.register
            if reg is None:
                raise ValueError(f"{self.op.value} needs a register")
            if self.op is Op.GET_PARAM:
                return bytes([head | reg.addr])
            if not reg.access.writable:
                raise ValueError(f"{reg.name} is read-only: SetParam would be WRONG_CMD")
            return bytes([head | reg.addr]) + reg.word(self.value).to_bytes(reg.nbytes, "big")
        if self.op in _TAKES_DIR:
            head |= _bit("DIR", self.dir)
        if self.op in _TAKES_ACT:
            head |= _bit("ACT", self.act) << 3
        bits = _ARG_BITS.get(self.op)
        if bits is None:
            return bytes([head])
        return bytes([head]) + _argument(self.op, bits, self.value).to_bytes(3, "big")

    @property
    def reply_length(self) -> int:
        """How many bytes the chip answers after the command byte (GetParam, GetStatus)."""
        if self.op is Op.GET_PARAM and self.register is not None:
            return self.register.nbytes
        return 2 if self.op is Op.GET_STATUS else 0


def _bit(name: str, value: int) -> int:
    if value not in (0, 1):
        raise ValueError(f"{name} is one bit, not {value}")
    return value


def _argument(op: Op, bits: int, value: int) -> int:
    if op in (Op.GO_TO, Op.GO_TO_DIR):
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        lo, hi = 0, (1 << bits) - 1
    if not lo <= value <= hi:
        raise ValueError(f"{op.value}: {value} is outside {lo}..{hi} ({bits} bits)")
    return value & ((1 << bits) - 1)


# the commands, as the host writes them
def set_param(register: Register, value: int) -> Command:
    return Command(Op.SET_PARAM, register=register, value=value)


def get_param(register: Register) -> Command:
    return Command(Op.GET_PARAM, register=register)


def run(direction: int, spd: int) -> Command:
    return Command(Op.RUN, dir=direction, value=spd)


def move(direction: int, n_step: int) -> Command:
    return Command(Op.MOVE, dir=direction, value=n_step)


def go_to(abs_pos: int) -> Command:
    return Command(Op.GO_TO, value=abs_pos)


def go_to_dir(direction: int, abs_pos: int) -> Command:
    return Command(Op.GO_TO_DIR, dir=direction, value=abs_pos)


def go_until(act: int, direction: int, spd: int) -> Command:
    return Command(Op.GO_UNTIL, dir=direction, act=act, value=spd)


def release_sw(act: int, direction: int) -> Command:
    return Command(Op.RELEASE_SW, dir=direction, act=act)


def step_clock(direction: int) -> Command:
    return Command(Op.STEP_CLOCK, dir=direction)


def simple(op: Op) -> Command:
    """A command of one byte and no argument (NOP, GoHome, SoftStop, GetStatus...)."""
    if CODE[op] not in _PLAIN and op is not Op.NOP:
        raise ValueError(f"{op.value} takes arguments")
    return Command(op)


# the chip's side: what a command byte is
@dataclass(frozen=True)
class Decoded:
    """A command byte as the chip reads it: ``argument`` bytes follow (0..3); ``register``:
    the register SetParam/GetParam names, None for an address the chip has none at;
    ``wrong``: not a command of this chip (WRONG_CMD at the end of the byte)."""

    op: Op
    dir: int = 0
    act: int = 0
    register: Register | None = None
    argument: int = 0
    wrong: bool = False

    @property
    def follows(self) -> int:
        """How many bytes follow the command byte in its slot of the chain: its argument's
        (written), or its answer's (GetParam: the register's; GetStatus: 2, read)."""
        if self.op is Op.GET_PARAM and self.register is not None:
            return self.register.nbytes
        if self.op is Op.GET_STATUS:
            return 2
        return self.argument

    def command(self, argument: bytes = b"") -> Command:
        """The command, with its argument bytes (their unused high bits ignored, as the
        chip ignores them)."""
        value = int.from_bytes(argument, "big")
        if self.register is not None:
            value = self.register.value(value)
        elif self.op in (Op.GO_TO, Op.GO_TO_DIR):
            value &= (1 << ABS_POS_BITS) - 1
            if value >> (ABS_POS_BITS - 1):
                value -= 1 << ABS_POS_BITS
        elif self.op in _ARG_BITS:
            value &= (1 << _ARG_BITS[self.op]) - 1
        return Command(self.op, dir=self.dir, act=self.act, register=self.register, value=value)


_WRONG = Decoded(Op.NOP, wrong=True)


def decode(chip: Chip, byte: int) -> Decoded:
    """What ``byte`` is to ``chip`` when it waits for a command."""
    if byte == NOP:
        return Decoded(Op.NOP)
    if byte & 0xC0 == 0x00:  # 00xP PPPP: SetParam (bit 5 = 0), GetParam (bit 5 = 1)
        reg = chip.registers.at(byte & 0x1F)
        getting = bool(byte & 0x20)
        if reg is None or (not getting and not reg.access.writable):
            return _WRONG
        if getting:
            return Decoded(Op.GET_PARAM, register=reg)
        return Decoded(Op.SET_PARAM, register=reg, argument=reg.nbytes)
    if byte in _PLAIN:
        return Decoded(_PLAIN[byte])
    for op in _TAKES_DIR:
        act_bit = 0x08 if op in _TAKES_ACT else 0
        if byte & ~(0x01 | act_bit) & 0xFF == CODE[op]:
            return Decoded(
                op,
                dir=byte & 1,
                act=(byte >> 3) & 1 if act_bit else 0,
                argument=3 if op in _ARG_BITS else 0,
            )
    if byte == CODE[Op.GO_TO]:
        return Decoded(Op.GO_TO, argument=3)
    return _WRONG
