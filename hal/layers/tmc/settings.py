"""A driver's settings and what they become: register values, the driver spec.

Pure data and functions (no state, no I/O; any thread): the layer's declaration
(``config.py``) builds :class:`TmcSettings` and :class:`TmcSpec` from ``[motors.tmc]``; the
driver writes the registers :func:`register_values` gives. What differs between the chips
(their current scaling) is asked of the settings' :class:`~motorctl.hal.layers.tmc.fields.Chip`.
"""

from __future__ import annotations

from dataclasses import dataclass

from motorctl.hal.layers.tmc.fields import Chip, F, Reg, mres_of, tstep_for
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.spec import AxisSpec, DriverSpec
from motorctl.hal.spi import DEFAULT_SPEED_HZ


@dataclass(frozen=True)
class TmcSettings:
    """One driver's configuration: plain values, checked by the config schema. The defaults
    are [motors.tmc]'s: config.py declares each key with the default written here."""

    chip: Chip = TMC2130  # tmc2130.TMC2130 or tmc5160.TMC5160
    sense_resistor: float = 0.0  # ohm; 0 = the chip's usual board value
    run_current: float = 0.8  # A rms
    hold_current: float = 0.4  # A rms
    hold_delay: int = 6  # IHOLDDELAY
    microsteps: int = 16
    interpolate: bool = True
    toff: int = 3
    hstrt: int = 4
    hend: int = 1
    tbl: int = 2
    stealthchop: bool = False
    tpowerdown: int = 10
    stall_threshold: int = 0  # SGT, -64..63: higher = less sensitive
    stall_filter: bool = False
    stall_min_speed: float = 0.0  # step/s below which the stall flag is ignored (TCOOLTHRS)
    clock_hz: float = 12e6  # fCLK: the internal clock unless CLK is driven
    invert_dir: bool = AxisSpec.invert_dir  # GCONF.shaft (used by the ramp generator)
    open_load: str = "fault"  # "fault", "warn" or "ignore"

    @property
    def sense_ohm(self) -> float:
        return self.sense_resistor or self.chip.default_sense_ohm


def register_values(s: TmcSettings) -> dict[int, int]:
    """The configuration registers for ``s``, in the order they are written; ValueError for
    a current the chip cannot drive."""
    cur = s.chip.current_setting(s.sense_ohm, s.run_current, s.hold_current)
    gconf = F.EN_PWM_MODE.put(0, int(s.stealthchop))
    gconf = F.SHAFT.put(gconf, int(s.invert_dir))
    chop = 0
    chop = F.TOFF.put(chop, s.toff)
    chop = F.HSTRT.put(chop, s.hstrt)
    chop = F.HEND.put(chop, s.hend)
    chop = F.TBL.put(chop, s.tbl)
    chop = F.MRES.put(chop, mres_of(s.microsteps))
    chop = F.INTPOL.put(chop, int(s.interpolate))
    scaled = s.chip.scale_registers(cur, chop)
    chop = scaled.pop(Reg.CHOPCONF)
    ihold = F.IHOLD.put(0, cur.ihold)
    ihold = F.IRUN.put(ihold, cur.irun)
    ihold = F.IHOLDDELAY.put(ihold, s.hold_delay)
    cool = F.SGT.put(0, s.stall_threshold)
    cool = F.SFILT.put(cool, int(s.stall_filter))
    regs: dict[int, int] = {Reg.GCONF: gconf, **scaled}
    regs[Reg.IHOLD_IRUN] = ihold
    regs[Reg.TPOWERDOWN] = s.tpowerdown
    regs[Reg.TCOOLTHRS] = tstep_for(s.stall_min_speed, s.microsteps, s.clock_hz)
    regs[Reg.COOLCONF] = cool
    regs[Reg.CHOPCONF] = chop
    return regs


@dataclass(frozen=True)
class TmcSpec(DriverSpec):
    """What the TMC layer needs to open one motor's driver: where, how fast, how configured
    (the defaults, as :class:`TmcSettings`'s, are [motors.tmc]'s)."""

    spi: str  # "/dev/spidevB.C"
    settings: TmcSettings
    spi_speed_hz: int = DEFAULT_SPEED_HZ
    ramp: bool = False  # TMC5160 motion-controller mode (its ramp generator moves the motor)
    ref_left_active_low: bool = False
    ref_right_active_low: bool = False
    disable_at_exit: bool = True

    @property
    def own_ramp(self) -> bool:
        return self.ramp

    @property
    def microsteps(self) -> int | None:
        return self.settings.microsteps
