"""The TMC2130's own registers, fields and constants (datasheet rev. 1.15), as data.

A STEP/DIR driver with an SPI configuration and status interface: no ramp generator. The
registers and fields both chips have are in ``fields.py``. Pure data: any thread.
"""

from __future__ import annotations

from typing import Final

from motorctl.hal.layers.tmc import fields
from motorctl.hal.layers.tmc.fields import Chip, Field


class Reg(fields.Reg):
    """The TMC2130's registers that motorctl uses: all shared with the TMC5160."""


class F(fields.F):
    """The shared fields and the TMC2130's own."""

    # CHOPCONF
    VSENSE: Final = Field(17)  # the sense voltage range: 1 = high sensitivity (VFS 0.18 V)


#: full-scale sense voltages [V] with CHOPCONF.vsense = 0 and = 1
VFS: Final = (0.32, 0.18)

TMC2130: Final = Chip(
    name="TMC2130",
    version=0x11,
    readable=frozenset(
        {Reg.GCONF, Reg.GSTAT, Reg.IOIN, Reg.TSTEP, Reg.MSCNT, Reg.CHOPCONF, Reg.DRV_STATUS}
    ),
    status_bits=4,
    has_ramp=False,
    has_s2vs=False,
    default_sense_ohm=0.11,
)
