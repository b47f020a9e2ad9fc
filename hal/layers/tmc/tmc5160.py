"""The TMC5160's own registers, fields and constants (datasheet rev. 1.14), as data.

Besides what it shares with the TMC2130 (``fields.py``): GLOBALSCALER, the ramp generator's
registers (motion-controller mode, SD_MODE low), the reference switch configuration
(SW_MODE) and status (RAMP_STAT), its short-to-supply flags, and the conversions between
steps/s, steps/s^2 and the ramp generator's units. Pure data and formulas: any thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from motorctl.hal.layers.tmc import fields
from motorctl.hal.layers.tmc.fields import Chip, Field


class Reg(fields.Reg):
    """The shared registers and the TMC5160's own."""

    GLOBALSCALER: Final = 0x0B
    RAMPMODE: Final = 0x20
    XACTUAL: Final = 0x21
    VACTUAL: Final = 0x22
    VSTART: Final = 0x23
    A1: Final = 0x24
    V1: Final = 0x25
    AMAX: Final = 0x26
    VMAX: Final = 0x27
    DMAX: Final = 0x28
    D1: Final = 0x2A
    VSTOP: Final = 0x2B
    TZEROWAIT: Final = 0x2C
    XTARGET: Final = 0x2D
    SW_MODE: Final = 0x34
    RAMP_STAT: Final = 0x35
    XLATCH: Final = 0x36


class F(fields.F):
    """The shared fields and the TMC5160's own."""

    # IOIN
    SD_MODE: Final = Field(6)  # TMC5160: 1 = external STEP/DIR, 0 = internal ramp generator
    # DRV_STATUS
    S2VSA: Final = Field(12)
    S2VSB: Final = Field(13)
    STEALTH: Final = Field(14)
    # SW_MODE
    STOP_L_ENABLE: Final = Field(0)
    STOP_R_ENABLE: Final = Field(1)
    POL_STOP_L: Final = Field(2)
    POL_STOP_R: Final = Field(3)
    LATCH_L_ACTIVE: Final = Field(5)
    LATCH_R_ACTIVE: Final = Field(7)
    SG_STOP: Final = Field(10)
    EN_SOFTSTOP: Final = Field(11)
    # RAMP_STAT
    STATUS_STOP_L: Final = Field(0)
    STATUS_STOP_R: Final = Field(1)
    STATUS_LATCH_L: Final = Field(2)
    STATUS_LATCH_R: Final = Field(3)
    EVENT_STOP_L: Final = Field(4)
    EVENT_STOP_R: Final = Field(5)
    EVENT_STOP_SG: Final = Field(6)
    EVENT_POS_REACHED: Final = Field(7)
    VELOCITY_REACHED: Final = Field(8)
    POSITION_REACHED: Final = Field(9)
    VZERO: Final = Field(10)


#: RAMP_STAT flags that are cleared by writing 1 (datasheet: R+WC)
RAMP_STAT_WC: Final = (
    F.STATUS_LATCH_L.mask
    | F.STATUS_LATCH_R.mask
    | F.EVENT_STOP_SG.mask
    | F.EVENT_POS_REACHED.mask
    | (1 << 12)
)


#: full-scale sense voltage [V] (fixed; GLOBALSCALER scales the current)
VFS: Final = 0.325

VSTOP_MIN: Final = 10  # datasheet: VSTOP >= VSTART, at least 10 recommended in positioning mode


TMC5160: Final = Chip(
    name="TMC5160",
    version=0x30,
    readable=frozenset(
        {
            Reg.GCONF,
            Reg.GSTAT,
            Reg.IOIN,
            Reg.TSTEP,
            Reg.RAMPMODE,
            Reg.XACTUAL,
            Reg.VACTUAL,
            Reg.XTARGET,
            Reg.SW_MODE,
            Reg.RAMP_STAT,
            Reg.XLATCH,
            Reg.MSCNT,
            Reg.CHOPCONF,
            Reg.DRV_STATUS,
        }
    ),
    status_bits=8,
    has_ramp=True,
    has_s2vs=True,
    default_sense_ohm=0.075,
)


@dataclass(frozen=True)
class RampUnits:
    """Conversions between steps/s, steps/s^2 and the TMC5160's ramp-generator units.

    Datasheet ("real world units"): v[steps/s] = VMAX * fCLK / 2^24 and
    a[steps/s^2] = AMAX * fCLK^2 / 2^41, in the steps of the configured microstep
    resolution (one step = what one STEP pulse would move).
    """

    clock_hz: float = 12e6

    VMAX_MAX: Final = (1 << 23) - 512
    AMAX_MAX: Final = (1 << 16) - 1

    def velocity(self, steps_s: float) -> int:
        return max(0, min(self.VMAX_MAX, round(abs(steps_s) * (1 << 24) / self.clock_hz)))

    def accel(self, steps_s2: float) -> int:
        v = round(abs(steps_s2) * (1 << 41) / (self.clock_hz * self.clock_hz))
        return max(1, min(self.AMAX_MAX, v))

    def decel(self, steps_s2: float) -> int:
        """As :meth:`accel`, rounded up: the chip brakes at least as hard as planned, so a
        stop planned by the engine never overshoots its target for rounding."""
        v = math.ceil(abs(steps_s2) * (1 << 41) / (self.clock_hz * self.clock_hz) - 1e-9)
        return max(1, min(self.AMAX_MAX, v))

    def steps_s(self, vreg: int) -> float:
        return vreg * self.clock_hz / (1 << 24)

    def steps_s2(self, areg: int) -> float:
        return areg * self.clock_hz * self.clock_hz / (1 << 41)


class RampMode:
    """RAMPMODE's values."""

    POSITION: Final = 0
    VELOCITY_POS: Final = 1
    VELOCITY_NEG: Final = 2
    HOLD: Final = 3
