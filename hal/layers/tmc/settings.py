"""A TMC driver's settings and what they become: currents, register values, the driver spec.

Pure data and functions (no state, no I/O; any thread): the config layer (``config.py``)
builds :class:`TmcSettings` and :class:`TmcSpec` from ``[motors.tmc]``; the driver writes the
registers :func:`register_values` gives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from motorctl.hal.layers.tmc import tmc2130, tmc5160
from motorctl.hal.layers.tmc.fields import Chip, F, Reg, mres_of, tstep_for
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160
from motorctl.hal.spec import DriverSpec

CHIPS: Final = {"tmc2130": TMC2130, "tmc5160": TMC5160}
CHIP_BY_VERSION: Final = {c.version: c for c in CHIPS.values()}


@dataclass(frozen=True)
class CurrentSetting:
    """IRUN/IHOLD current scales and the range they are in (vsense or GLOBALSCALER)."""

    irun: int
    ihold: int
    vsense: int = 0  # TMC2130
    globalscaler: int = 0  # TMC5160: register value, 0 means 256

    def rms(self, chip: Chip, sense_ohm: float, cs: int) -> float:
        """The RMS coil current [A] that current scale ``cs`` gives (datasheet formula)."""
        if chip is TMC2130:
            vfs = tmc2130.VFS[self.vsense]
            return (cs + 1) / 32 * vfs / (sense_ohm + 0.02) / math.sqrt(2)
        gs = self.globalscaler or 256
        return gs / 256 * (cs + 1) / 32 * tmc5160.VFS / sense_ohm / math.sqrt(2)


def current_setting(chip: Chip, sense_ohm: float, run_a: float, hold_a: float) -> CurrentSetting:
    """IRUN/IHOLD (and vsense or GLOBALSCALER) for RMS currents; ValueError when impossible."""
    if sense_ohm <= 0:
        raise ValueError("sense_resistor must be > 0")
    if run_a <= 0 or hold_a < 0 or hold_a > run_a:
        raise ValueError("currents must satisfy 0 <= hold_current <= run_current, run > 0")

    def cs_for(current: float, full_scale: float) -> int:
        return max(0, min(31, round(32 * current / full_scale) - 1))

    if chip is TMC2130:
        for vsense in (1, 0):  # the high-sensitivity range gives finer steps when it suffices
            fs = tmc2130.VFS[vsense] / (sense_ohm + 0.02) / math.sqrt(2)
            if run_a <= fs * 1.0001:
                return CurrentSetting(cs_for(run_a, fs), cs_for(hold_a, fs), vsense=vsense)
        top = tmc2130.VFS[0] / (sense_ohm + 0.02) / math.sqrt(2)
        raise ValueError(
            f"run_current {run_a} A is above the {top:.2f} A a TMC2130 gives with a "
            f"{sense_ohm} ohm sense resistor"
        )
    fs256 = tmc5160.VFS / sense_ohm / math.sqrt(2)
    if run_a > fs256 * 1.0001:
        raise ValueError(
            f"run_current {run_a} A is above the {fs256:.2f} A a TMC5160 gives with a "
            f"{sense_ohm} ohm sense resistor"
        )
    gs = max(32, min(256, math.ceil(256 * run_a / fs256)))
    fs = fs256 * gs / 256
    return CurrentSetting(cs_for(run_a, fs), cs_for(hold_a, fs), globalscaler=gs % 256)


@dataclass(frozen=True)
class TmcSettings:
    """One driver's configuration: plain values, checked by the config schema."""

    chip: str = "tmc2130"  # "tmc2130" or "tmc5160"
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
    invert_dir: bool = False  # GCONF.shaft (used by the ramp generator)
    open_load: str = "fault"  # "fault", "warn" or "ignore"
    poll_ms: float = 50.0  # DRV_STATUS poll period of the monitor thread

    @property
    def kind(self) -> Chip:
        try:
            return CHIPS[self.chip]
        except KeyError:
            raise ValueError(f"unknown driver chip {self.chip!r}: tmc2130 or tmc5160") from None

    @property
    def sense_ohm(self) -> float:
        return self.sense_resistor or self.kind.default_sense_ohm


def register_values(s: TmcSettings) -> dict[int, int]:
    """The configuration registers for ``s``, in the order they are written."""
    chip = s.kind
    cur = current_setting(chip, s.sense_ohm, s.run_current, s.hold_current)
    gconf = F.EN_PWM_MODE.put(0, int(s.stealthchop))
    gconf = F.SHAFT.put(gconf, int(s.invert_dir))
    chop = 0
    chop = F.TOFF.put(chop, s.toff)
    chop = F.HSTRT.put(chop, s.hstrt)
    chop = F.HEND.put(chop, s.hend)
    chop = F.TBL.put(chop, s.tbl)
    chop = F.MRES.put(chop, mres_of(s.microsteps))
    chop = F.INTPOL.put(chop, int(s.interpolate))
    if chip is TMC2130:
        chop = tmc2130.F.VSENSE.put(chop, cur.vsense)
    ihold = F.IHOLD.put(0, cur.ihold)
    ihold = F.IRUN.put(ihold, cur.irun)
    ihold = F.IHOLDDELAY.put(ihold, s.hold_delay)
    cool = F.SGT.put(0, s.stall_threshold)
    cool = F.SFILT.put(cool, int(s.stall_filter))
    regs: dict[int, int] = {Reg.GCONF: gconf}
    if chip is TMC5160:
        regs[tmc5160.Reg.GLOBALSCALER] = cur.globalscaler
    regs[Reg.IHOLD_IRUN] = ihold
    regs[Reg.TPOWERDOWN] = s.tpowerdown
    regs[Reg.TCOOLTHRS] = tstep_for(s.stall_min_speed, s.microsteps, s.clock_hz)
    regs[Reg.COOLCONF] = cool
    regs[Reg.CHOPCONF] = chop
    return regs


@dataclass(frozen=True)
class TmcSpec(DriverSpec):
    """What the SPI layer needs to open one motor's driver: where, how fast, how configured."""

    spi: str  # "/dev/spidevB.C"
    settings: TmcSettings
    spi_speed_hz: int = 1_000_000
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
