"""What one LSB of each speed and acceleration register is, in full steps per second (per
second squared), from the chip's tick of 250 ns (its 16 MHz clock; every model, every
oscillator setting: L6470 9.1.4-9.1.11, the same sections in the other datasheets).

| register | format | full step/s (s^2) per LSB | register range |
|---|---|---|---|
| SPEED, Run's and GoUntil's SPD | step/tick, 0.28 | 2^-28 / tick = 0.0149 | 0..2^20-1 |
| ACC, DEC | step/tick^2, 0.40 | 2^-40 / tick^2 = 14.55 | 1..0xFFE |
| MAX_SPEED | step/tick, 0.18 | 2^-18 / tick = 15.26 | 1..0x3FF |
| MIN_SPEED | step/tick, 0.24 | 2^-24 / tick = 0.238 | 0..0xFFF |
| FS_SPD | step/tick, 0.18, +0.5 | (FS_SPD + 0.5) x 2^-18 / tick | 0..0x3FF |
| INT_SPEED | step/tick, 0.26 | 2^-26 / tick = 0.0596 | 0..0x3FFF |

The speeds are in FULL steps whatever the step mode; positions (ABS_POS, MARK, Move's
N_STEP) count microsteps of the step mode STEP_MODE.STEP_SEL selects.

ACC = 0xFFF is reserved on the L6470 and L6472 and means "infinite acceleration" on the
L6480 and powerSTEP01; neither is a ramp, so the ramps' range stops at 0xFFE on every model
(DEC likewise, one rule). 0 would be no ramp at all (the motor would never leave MIN_SPEED),
MAX_SPEED 0 no motion: both ranges start at 1.

The values are exact fractions (the LSBs are powers of two over 4,000,000), so a register
value converted to step/s and back is the same register value. Pure: any thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from typing import Final

#: the chip's tick: 250 ns
TICK: Final = Fraction(1, 4_000_000)


@dataclass(frozen=True)
class Scale:
    """A register that holds a speed or an acceleration: ``value = (reg + offset) * lsb``
    [full step/s or full step/s^2], ``reg`` in ``lo..hi``."""

    name: str
    lsb: Fraction
    lo: int
    hi: int
    offset: Fraction = Fraction(0)

    def value(self, reg: int) -> Fraction:
        """The speed (acceleration) register value ``reg`` stands for."""
        return (reg + self.offset) * self.lsb

    @property
    def smallest(self) -> Fraction:
        return self.value(self.lo)

    @property
    def largest(self) -> Fraction:
        return self.value(self.hi)

    def floor(self, value: Fraction) -> int:
        """The largest register value whose speed does not exceed ``value`` (unclamped: may
        fall outside ``lo..hi``)."""
        return int((value / self.lsb - self.offset) // 1)


SPEED: Final = Scale("SPEED", Fraction(1, 2**28) / TICK, 0, 2**20 - 1)
ACC: Final = Scale("ACC", Fraction(1, 2**40) / TICK**2, 1, 0xFFE)
DEC: Final = Scale("DEC", Fraction(1, 2**40) / TICK**2, 1, 0xFFE)
MAX_SPEED: Final = Scale("MAX_SPEED", Fraction(1, 2**18) / TICK, 1, 0x3FF)
MIN_SPEED: Final = Scale("MIN_SPEED", Fraction(1, 2**24) / TICK, 0, 0xFFF)
FS_SPD: Final = Scale("FS_SPD", Fraction(1, 2**18) / TICK, 0, 0x3FF, Fraction(1, 2))
INT_SPEED: Final = Scale("INT_SPEED", Fraction(1, 2**26) / TICK, 0, 0x3FFF)

#: ReleaseSW runs at MIN_SPEED, but never slower than this (nor when LSPD_OPT is set)
RELEASE_SW_MIN_SPEED: Final = Fraction(5)  # full step/s
