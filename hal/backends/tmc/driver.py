"""Trinamic TMC2130 and TMC5160 stepper drivers over SPI: registers, datagrams, start-up, status.

Everything here follows the chips' datasheets (TMC2130 rev. 1.15, TMC5160 rev. 1.14):

- A datagram is 40 bits, MSB first, SPI mode 3: one address byte (bit 7 = write) and 32 data
  bits. The reply's first byte is the SPI status byte; its 32 data bits are *pipelined*: they
  answer the previous datagram (a read's register contents, or the data a write carried).
  So a read is two datagrams, and the datagram after a write echoes the written bits, which
  is how write-only registers are verified here (the chip received exactly these bits).
- The version sits in IOIN bits 31..24: 0x11 for the TMC2130, 0x30 for the TMC5160.
- DRV_STATUS carries the fault flags (ot, otpw, s2ga/s2gb, on the TMC5160 s2vsa/s2vsb,
  ola/olb), the stallGuard flag and standstill (stst).

Threads: a :class:`TmcDriver` is started by the thread that builds the hardware; from then on
:meth:`TmcDriver.poll` runs in the :class:`DriverMonitor` thread only, and the step thread
calls :meth:`TmcDriver.status`, which returns the monitor's last result without any I/O
(a reference read: never blocks). Ramp-generator calls of :class:`Tmc5160` come from the
thread of the executor that owns the motor. All SPI traffic of one bus is serialised by its
bus lock (:class:`~motorctl.hal.backends.tmc.spi.SpiBuses`); a pipelined read holds it for
both datagrams.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Final

from motorctl.hal.backends.tmc.spi import SpiDevice, SpiError
from motorctl.hal.interfaces import DriverStatus, HalError, StepperDriver

log = logging.getLogger("motorctl.tmc")

WRITE: Final = 0x80


class TmcError(HalError):
    """A driver chip that cannot be used as configured; the message names its SPI device."""


# ------------------------------------------------------------------------------ registers


class Reg:
    """Register addresses (both chips share the ones they have in common)."""

    GCONF: Final = 0x00
    GSTAT: Final = 0x01
    IOIN: Final = 0x04
    GLOBALSCALER: Final = 0x0B
    IHOLD_IRUN: Final = 0x10
    TPOWERDOWN: Final = 0x11
    TSTEP: Final = 0x12
    TPWMTHRS: Final = 0x13
    TCOOLTHRS: Final = 0x14
    THIGH: Final = 0x15
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
    MSCNT: Final = 0x6A
    CHOPCONF: Final = 0x6C
    COOLCONF: Final = 0x6D
    DRV_STATUS: Final = 0x6F
    PWMCONF: Final = 0x70


REG_NAMES: Final = {
    v: k for k, v in vars(Reg).items() if not k.startswith("_") and isinstance(v, int)
}


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


class F:
    """The fields motorctl sets or reads."""

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
    SD_MODE: Final = Field(6)  # TMC5160: 1 = external STEP/DIR, 0 = internal ramp generator
    # IHOLD_IRUN
    IHOLD: Final = Field(0, 5)
    IRUN: Final = Field(8, 5)
    IHOLDDELAY: Final = Field(16, 4)
    # CHOPCONF
    TOFF: Final = Field(0, 4)
    HSTRT: Final = Field(4, 3)
    HEND: Final = Field(7, 4)
    TBL: Final = Field(15, 2)
    VSENSE: Final = Field(17)  # TMC2130 only
    MRES: Final = Field(24, 4)
    INTPOL: Final = Field(28)
    # COOLCONF
    SGT: Final = Field(16, 7, signed=True)
    SFILT: Final = Field(24)
    # DRV_STATUS
    SG_RESULT: Final = Field(0, 10)
    S2VSA: Final = Field(12)  # TMC5160 only
    S2VSB: Final = Field(13)  # TMC5160 only
    STEALTH: Final = Field(14)  # TMC5160 only
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
    # SW_MODE (TMC5160)
    STOP_L_ENABLE: Final = Field(0)
    STOP_R_ENABLE: Final = Field(1)
    POL_STOP_L: Final = Field(2)
    POL_STOP_R: Final = Field(3)
    LATCH_L_ACTIVE: Final = Field(5)
    LATCH_R_ACTIVE: Final = Field(7)
    SG_STOP: Final = Field(10)
    EN_SOFTSTOP: Final = Field(11)
    # RAMP_STAT (TMC5160)
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
    F.STATUS_LATCH_L.mask | F.STATUS_LATCH_R.mask | F.EVENT_STOP_SG.mask
    | F.EVENT_POS_REACHED.mask | (1 << 12)
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


def signed32(v: int) -> int:
    return v - (1 << 32) if v & (1 << 31) else v


def mres_of(microsteps: int) -> int:
    """CHOPCONF.MRES for ``microsteps`` per full step (256 -> 0, ..., 1 -> 8)."""
    if microsteps < 1 or microsteps > 256 or microsteps & (microsteps - 1):
        raise ValueError(f"microsteps must be a power of two from 1 to 256, not {microsteps}")
    return 8 - int(math.log2(microsteps))


# ------------------------------------------------------------------------------ chips


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

TMC5160: Final = Chip(
    name="TMC5160",
    version=0x30,
    readable=frozenset(
        {
            Reg.GCONF, Reg.GSTAT, Reg.IOIN, Reg.TSTEP, Reg.RAMPMODE, Reg.XACTUAL, Reg.VACTUAL,
            Reg.XTARGET, Reg.SW_MODE, Reg.RAMP_STAT, Reg.XLATCH, Reg.MSCNT, Reg.CHOPCONF,
            Reg.DRV_STATUS,
        }
    ),
    status_bits=8,
    has_ramp=True,
    has_s2vs=True,
    default_sense_ohm=0.075,
)

CHIPS: Final = {"tmc2130": TMC2130, "tmc5160": TMC5160}
CHIP_BY_VERSION: Final = {c.version: c for c in CHIPS.values()}


# ------------------------------------------------------------------------------ currents

#: full-scale sense voltages [V]: TMC2130 vsense=0 / vsense=1; TMC5160 (fixed)
VFS_2130: Final = (0.32, 0.18)
VFS_5160: Final = 0.325


@dataclass(frozen=True)
class CurrentSetting:
    irun: int
    ihold: int
    vsense: int = 0  # TMC2130
    globalscaler: int = 0  # TMC5160: register value, 0 means 256

    def rms(self, chip: Chip, sense_ohm: float, cs: int) -> float:
        """The RMS coil current [A] that current scale ``cs`` gives (datasheet formula)."""
        if chip is TMC2130:
            vfs = VFS_2130[self.vsense]
            return (cs + 1) / 32 * vfs / (sense_ohm + 0.02) / math.sqrt(2)
        gs = self.globalscaler or 256
        return gs / 256 * (cs + 1) / 32 * VFS_5160 / sense_ohm / math.sqrt(2)


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
            fs = VFS_2130[vsense] / (sense_ohm + 0.02) / math.sqrt(2)
            if run_a <= fs * 1.0001:
                return CurrentSetting(cs_for(run_a, fs), cs_for(hold_a, fs), vsense=vsense)
        top = VFS_2130[0] / (sense_ohm + 0.02) / math.sqrt(2)
        raise ValueError(
            f"run_current {run_a} A is above the {top:.2f} A a TMC2130 gives with a "
            f"{sense_ohm} ohm sense resistor"
        )
    fs256 = VFS_5160 / sense_ohm / math.sqrt(2)
    if run_a > fs256 * 1.0001:
        raise ValueError(
            f"run_current {run_a} A is above the {fs256:.2f} A a TMC5160 gives with a "
            f"{sense_ohm} ohm sense resistor"
        )
    gs = max(32, min(256, math.ceil(256 * run_a / fs256)))
    fs = fs256 * gs / 256
    return CurrentSetting(cs_for(run_a, fs), cs_for(hold_a, fs), globalscaler=gs % 256)


# ------------------------------------------------------------------------------ settings


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


def tstep_for(speed: float, microsteps: int, clock_hz: float) -> int:
    """TSTEP (clocks between 1/256 microsteps, 20 bits) at ``speed`` steps/s; 0 speed -> 0."""
    if speed <= 0:
        return 0
    per_256 = speed * (256 / microsteps)
    return max(1, min((1 << 20) - 1, int(clock_hz / per_256)))


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
        chop = F.VSENSE.put(chop, cur.vsense)
    ihold = F.IHOLD.put(0, cur.ihold)
    ihold = F.IRUN.put(ihold, cur.irun)
    ihold = F.IHOLDDELAY.put(ihold, s.hold_delay)
    cool = F.SGT.put(0, s.stall_threshold)
    cool = F.SFILT.put(cool, int(s.stall_filter))
    regs: dict[int, int] = {Reg.GCONF: gconf}
    if chip is TMC5160:
        regs[Reg.GLOBALSCALER] = cur.globalscaler
    regs[Reg.IHOLD_IRUN] = ihold
    regs[Reg.TPOWERDOWN] = s.tpowerdown
    regs[Reg.TCOOLTHRS] = tstep_for(s.stall_min_speed, s.microsteps, s.clock_hz)
    regs[Reg.COOLCONF] = cool
    regs[Reg.CHOPCONF] = chop
    return regs


@dataclass(frozen=True)
class TmcSpec:
    """What a backend needs to open one motor's driver: where, how fast, how configured."""

    spi: str  # "/dev/spidevB.C"
    settings: TmcSettings
    spi_speed_hz: int = 1_000_000
    ramp: bool = False  # TMC5160 motion-controller mode (its ramp generator moves the motor)
    ref_left_active_low: bool = False
    ref_right_active_low: bool = False
    disable_at_exit: bool = True


# ------------------------------------------------------------------------------ decoding


@dataclass(frozen=True)
class DrvStatus:
    """A decoded DRV_STATUS word."""

    raw: int
    chip: Chip

    def flag(self, f: Field) -> bool:
        return bool(f.get(self.raw))

    @property
    def stallguard(self) -> bool:
        return self.flag(F.STALLGUARD)

    @property
    def standstill(self) -> bool:
        return self.flag(F.STST)

    def faults(self) -> list[str]:
        """Conditions that disable the driver: over-temperature and shorts."""
        out = []
        if self.flag(F.OT):
            out.append("over-temperature (ot)")
        for f, text in ((F.S2GA, "short to ground on phase A (s2ga)"),
                        (F.S2GB, "short to ground on phase B (s2gb)")):
            if self.flag(f):
                out.append(text)
        if self.chip.has_s2vs:
            for f, text in ((F.S2VSA, "short to supply on phase A (s2vsa)"),
                            (F.S2VSB, "short to supply on phase B (s2vsb)")):
                if self.flag(f):
                    out.append(text)
        return out

    @property
    def shorted(self) -> bool:
        flags = [F.S2GA, F.S2GB] + ([F.S2VSA, F.S2VSB] if self.chip.has_s2vs else [])
        return any(self.flag(f) for f in flags)

    def open_load(self) -> list[str]:
        """Open-load flags; the datasheet says they are valid only in slow motion."""
        return [t for f, t in ((F.OLA, "open load on phase A (ola)"),
                               (F.OLB, "open load on phase B (olb)")) if self.flag(f)]

    def describe(self) -> str:
        """All flags and values, as ``--probe`` prints them."""
        names = ["stst", "olb", "ola", "s2gb", "s2ga", "otpw", "ot", "stallGuard", "fsactive"]
        fields = [F.STST, F.OLB, F.OLA, F.S2GB, F.S2GA, F.OTPW, F.OT, F.STALLGUARD, F.FSACTIVE]
        if self.chip.has_s2vs:
            names += ["stealth", "s2vsb", "s2vsa"]
            fields += [F.STEALTH, F.S2VSB, F.S2VSA]
        on = [n for n, f in zip(names, fields, strict=True) if self.flag(f)]
        return (
            f"DRV_STATUS=0x{self.raw:08x} SG_RESULT={F.SG_RESULT.get(self.raw)} "
            f"CS_ACTUAL={F.CS_ACTUAL.get(self.raw)} flags: {' '.join(on) or 'none'}"
        )


def decode_spi_status(byte: int, chip: Chip) -> list[str]:
    return [n for i, n in enumerate(SPI_STATUS_BITS[: chip.status_bits]) if byte >> i & 1]


# ------------------------------------------------------------------------------ the link


class TmcLink:
    """Register access to one chip: 40-bit datagrams, pipelined reads, write echo checks.

    Counts the rising edges of every SPI status flag (``flag_counts``); ``last_status`` is the
    most recent status byte.
    """

    def __init__(self, device: SpiDevice, chip: Chip) -> None:
        self.device = device
        self.chip = chip
        self.last_status = 0
        self.flag_counts = dict.fromkeys(SPI_STATUS_BITS[: chip.status_bits], 0)

    def _datagram(self, addr: int, value: int, write: bool) -> tuple[int, int]:
        tx = bytes([addr | (WRITE if write else 0)]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
        rx = self.device.xfer(tx)
        status = rx[0]
        rising = status & ~self.last_status
        for i, name in enumerate(SPI_STATUS_BITS[: self.chip.status_bits]):
            if rising >> i & 1:
                self.flag_counts[name] += 1
        self.last_status = status
        return status, int.from_bytes(rx[1:5], "big")

    def read_many(self, addrs: Sequence[int]) -> list[int]:
        """Read registers in one bus session: n + 1 datagrams, each reply answering the last."""
        if not addrs:
            return []
        out: list[int] = []
        with self.device.session():
            self._datagram(addrs[0], 0, write=False)
            for nxt in [*addrs[1:], addrs[-1]]:  # the last is repeated to fetch its answer
                out.append(self._datagram(nxt, 0, write=False)[1])
        return out

    def read(self, addr: int) -> int:
        return self.read_many([addr])[0]

    def write(self, addr: int, value: int) -> None:
        """Write and check the echo in the next datagram's reply; TmcError when it differs."""
        value &= 0xFFFFFFFF
        with self.device.session():
            self._datagram(addr, value, write=True)
            echo = self._datagram(Reg.IOIN, 0, write=False)[1]
        if echo != value:
            raise TmcError(
                f"{self.device.path}: {self.chip.name} did not receive {REG_NAMES[addr]} "
                f"= 0x{value:08x} intact (it echoed 0x{echo:08x}); check the SPI wiring "
                "(MOSI/MISO/SCK, a common ground) and lower spi_speed_hz"
            )


# ------------------------------------------------------------------------------ the driver


def identify(link: TmcLink) -> int:
    """The chip's version from IOIN; TmcError naming the device when nothing answers."""
    ioin = link.read(Reg.IOIN)
    version = F.VERSION.get(ioin)
    if ioin in (0, 0xFFFFFFFF):
        raise TmcError(
            f"{link.device.path}: no driver chip answers (IOIN reads 0x{ioin:08x}); check "
            "that the driver has logic power (VIO) and motor power (VM), the wiring of "
            "SCK/SDI/SDO/CSN, and that the bus and chip select are right"
        )
    return version


class TmcDriver(StepperDriver):
    """One TMC2130 or TMC5160: started once, polled by the monitor, read by the step path."""

    def __init__(self, name: str, device: SpiDevice, settings: TmcSettings) -> None:
        self.name = name
        self.settings = settings
        self.chip = settings.kind
        self.device = device
        self.link = TmcLink(device, self.chip)
        self.regs = register_values(settings)  # ValueError for an impossible configuration
        self._status = DriverStatus()
        self._transient: str | None = None  # reported until read once and healthy again
        self._transient_out = False  # the transient is in the published status
        self._disabled: str | None = None  # a short: the output stage is off until restart
        self.drv: DrvStatus | None = None
        self.tstep = (1 << 20) - 1
        self.gstat = 0
        self.polls = 0
        self.resets = 0  # chip resets seen while running (the ramp executor watches it)
        self.spi_errors = 0
        self.fault_counts: dict[str, int] = {}
        self.warning_counts: dict[str, int] = {}
        self._last_conditions: frozenset[str] = frozenset()
        self._lock = threading.Lock()

    # -- start ---------------------------------------------------------------------
    def start(self) -> None:
        """Open the device, check the chip, write the configuration and verify it."""
        self.device.open()
        try:
            self._bring_up()
        except SpiError as exc:
            self.device.close()
            raise TmcError(f"{self.name}: {exc}") from exc
        except BaseException:
            self.device.close()
            raise

    def _bring_up(self) -> None:
        """Check the chip's version and configure it (the device is open)."""
        version = identify(self.link)
        if version != self.chip.version:
            other = CHIP_BY_VERSION.get(version)
            found = f"a {other.name}" if other else f"an unknown chip (version 0x{version:02x})"
            raise TmcError(
                f"{self.device.path} ({self.name}): configured as {self.chip.name} "
                f"(IOIN version 0x{self.chip.version:02x}) but found {found}; set "
                f"driver = \"{other.name.lower() if other else '...'}\" or check which "
                "chip select this driver is wired to"
            )
        self.configure()

    def configure(self) -> None:
        """Write every configuration register, then read back the readable ones."""
        link = self.link
        chop = self.regs[Reg.CHOPCONF]
        link.write(Reg.CHOPCONF, F.TOFF.put(chop, 0))  # TOFF=0 clears latched short flags
        self.clear_gstat()
        for addr, value in self.regs.items():
            link.write(addr, value)
        self.verify()

    def reinit(self) -> None:
        """After a reset of the chip: its whole set-up again."""
        self.configure()

    def verify(self) -> None:
        readable = [a for a in self.regs if a in self.chip.readable]
        got = self.link.read_many(readable)
        for addr, value in zip(readable, got, strict=True):
            if value != self.regs[addr]:
                raise TmcError(
                    f"{self.device.path} ({self.name}): {REG_NAMES[addr]} reads back "
                    f"0x{value:08x}, 0x{self.regs[addr]:08x} was written; the chip may have "
                    "been reset (check VM) or the SPI wiring is unreliable"
                )

    def clear_gstat(self) -> int:
        """Read GSTAT (clears it on the TMC2130) and write 1s back (clears it on the TMC5160)."""
        gstat = self.link.read(Reg.GSTAT)
        if self.chip is TMC5160:
            self.link.write(Reg.GSTAT, 0x7)
        self.gstat = gstat
        return gstat

    def close(self) -> None:
        """Leave the motor unpowered (TOFF = 0) and close the device; errors are logged only."""
        try:
            self.link.write(Reg.CHOPCONF, F.TOFF.put(self.regs[Reg.CHOPCONF], 0))
        except (SpiError, TmcError) as exc:
            log.warning("%s: could not disable the driver at shutdown: %s", self.name, exc)
        self.device.close()

    # -- the step path ---------------------------------------------------------------
    def status(self) -> DriverStatus:
        """The monitor's latest verdict, without I/O. A transient fault is then forgotten
        once the chip is healthy again (so StopMove can clear it)."""
        with self._lock:
            if self._transient_out:  # the reader sees it now: forget it from the next poll
                self._transient = None
                self._transient_out = False
            return self._status

    # -- the monitor thread ------------------------------------------------------------
    def poll(self) -> DriverStatus:
        """Read DRV_STATUS and TSTEP, decode, latch; SPI errors become a latched fault."""
        self.polls += 1
        try:
            drv_raw, tstep = self.link.read_many([Reg.DRV_STATUS, Reg.TSTEP])
            if self.link.last_status & 0x3:  # reset_flag or driver_error: GSTAT says which
                self._handle_gstat(self.clear_gstat())
        except (SpiError, TmcError) as exc:
            self.spi_errors += 1
            self._set_transient(f"SPI: {exc}")
            return self._publish(None)
        drv = DrvStatus(drv_raw, self.chip)
        self.drv = drv
        self.tstep = tstep
        if drv.shorted and self._disabled is None:
            self._disabled = ", ".join(drv.faults()) + " - driver disabled; fix the wiring " \
                "and restart motorctld"
            try:
                self.link.write(Reg.CHOPCONF, F.TOFF.put(self.regs[Reg.CHOPCONF], 0))
            except (SpiError, TmcError) as exc:
                log.error("%s: could not disable the shorted driver: %s", self.name, exc)
        return self._publish(drv)

    def _handle_gstat(self, gstat: int) -> None:
        if F.RESET.get(gstat):
            self.resets += 1
            try:
                self.reinit()
                self._set_transient(
                    "driver was reset and lost its configuration (reconfigured); check the "
                    "motor supply VM and the logic supply VIO"
                )
            except (SpiError, TmcError) as exc:
                self._set_transient(f"driver was reset and could not be reconfigured: {exc}")
        if self.chip is TMC5160 and F.UV_CP.get(gstat):
            self._set_transient("charge pump undervoltage (GSTAT.uv_cp); check VM")

    def _set_transient(self, text: str) -> None:
        with self._lock:
            self._transient = text
            self._transient_out = False
        self._count(self.fault_counts, [text.split(";")[0].split(" (")[0]])

    def _count(self, table: dict[str, int], names: Iterable[str]) -> None:
        for n in names:
            table[n] = table.get(n, 0) + 1

    def _publish(self, drv: DrvStatus | None) -> DriverStatus:
        faults: list[str] = []
        if self._disabled is not None:
            faults.append(self._disabled)
        stall = False
        if drv is not None:
            current = [f for f in drv.faults() if self._disabled is None]
            faults += current
            moving = not drv.standstill
            if moving and self.settings.open_load != "ignore":
                ol = drv.open_load()
                if self.settings.open_load == "fault":
                    faults += ol
                else:
                    self._count(self.warning_counts, ol)
            if drv.flag(F.OTPW):
                self._count(self.warning_counts, ["over-temperature pre-warning (otpw)"])
            thr = self.regs[Reg.TCOOLTHRS]
            fast_enough = thr == 0 or self.tstep <= thr
            stall = drv.stallguard and moving and fast_enough
            conditions = frozenset(faults)
            self._count(self.fault_counts, conditions - self._last_conditions)
            self._last_conditions = conditions
        with self._lock:
            if self._transient is not None:
                faults.append(self._transient)
                self._transient_out = True
            status = DriverStatus(fault="; ".join(faults) or None, stall=stall)
            self._status = status
        return status

    # -- reporting -----------------------------------------------------------------------
    def stats(self) -> dict[str, object]:
        return {
            "chip": self.chip.name,
            "device": self.device.path,
            "polls": self.polls,
            "spi_errors": self.spi_errors,
            "spi_status_counts": dict(self.link.flag_counts),
            "fault_counts": dict(self.fault_counts),
            "warning_counts": dict(self.warning_counts),
            "drv_status": None if self.drv is None else f"0x{self.drv.raw:08x}",
        }

    def probe(self) -> list[str]:
        """Read-only report for ``motorctld --probe``: chip, version, DRV_STATUS decoded.

        Reads IOIN and DRV_STATUS only (not GSTAT, which a TMC2130 clears on reading)."""
        self.device.open()
        try:
            version = identify(self.link)
            ioin, drv_raw = self.link.read_many([Reg.IOIN, Reg.DRV_STATUS])
        except (SpiError, TmcError) as exc:
            return [f"{self.name}: {exc}"]
        other = CHIP_BY_VERSION.get(version)
        found = other.name if other else f"unknown chip (version 0x{version:02x})"
        verdict = "ok" if other is self.chip else f"MISMATCH: configured {self.chip.name}"
        chip = other or self.chip
        lines = [
            f"{self.name}: {self.device.path}: {found} (IOIN=0x{ioin:08x}) {verdict}",
            f"  {DrvStatus(drv_raw, chip).describe()}",
            f"  SPI status: "
            f"{' '.join(decode_spi_status(self.link.last_status, chip)) or 'none'}",
        ]
        if chip is TMC5160:
            lines.append(
                f"  SD_MODE={F.SD_MODE.get(ioin)} "
                f"({'external STEP/DIR' if F.SD_MODE.get(ioin) else 'internal ramp generator'})"
            )
        return lines


# ------------------------------------------------------------------------------ TMC5160 ramp


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
    POSITION: Final = 0
    VELOCITY_POS: Final = 1
    VELOCITY_NEG: Final = 2
    HOLD: Final = 3


@dataclass(frozen=True)
class RampState:
    xactual: int
    vactual: int
    ramp_stat: int

    def flag(self, f: Field) -> bool:
        return bool(f.get(self.ramp_stat))

    @property
    def stopped(self) -> bool:
        return self.vactual == 0


@dataclass
class RefSwitches:
    """The TMC5160's REFL/REFR inputs: polarity (True = active low)."""

    left_active_low: bool = False
    right_active_low: bool = False


VSTOP_MIN: Final = 10  # datasheet: VSTOP >= VSTART, at least 10 recommended in positioning mode


class Tmc5160(TmcDriver):
    """A TMC5160 whose own ramp generator moves the motor (SD_MODE low)."""

    def __init__(
        self,
        name: str,
        device: SpiDevice,
        settings: TmcSettings,
        switches: RefSwitches | None = None,
    ) -> None:
        if settings.kind is not TMC5160:
            raise ValueError("the ramp generator needs a TMC5160")
        super().__init__(name, device, settings)
        self.units = RampUnits(settings.clock_hz)
        self.switches = switches or RefSwitches()
        self.sw_mode = self._sw_mode_base()
        self.sg_stopped = False  # the chip stopped itself on stallGuard (set by the executor)

    def _sw_mode_base(self) -> int:
        sw = F.POL_STOP_L.put(0, int(self.switches.left_active_low))
        return F.POL_STOP_R.put(sw, int(self.switches.right_active_low))

    def _bring_up(self) -> None:
        super()._bring_up()
        if F.SD_MODE.get(self.link.read(Reg.IOIN)):
            raise TmcError(
                f"{self.device.path} ({self.name}): the TMC5160's SD_MODE pin is high, so "
                "it takes STEP/DIR and its ramp generator is off; tie SD_MODE to GND or "
                "configure the motor with mode = \"step_dir\""
            )
        self.ramp_init()

    def reinit(self) -> None:
        """A reset cleared the ramp registers too (and XACTUAL: the position is lost)."""
        self.configure()
        self.ramp_init()

    def ramp_init(self) -> None:
        """Hold still where it is, with the ramp registers the datasheet requires non-zero."""
        link = self.link
        x = signed32(link.read(Reg.XACTUAL))
        link.write(Reg.RAMPMODE, RampMode.HOLD)
        link.write(Reg.VMAX, 0)
        link.write(Reg.XTARGET, x)
        link.write(Reg.VSTART, 0)
        link.write(Reg.V1, 0)  # single acceleration phase: AMAX/DMAX only
        link.write(Reg.VSTOP, VSTOP_MIN)
        link.write(Reg.TZEROWAIT, 0)
        link.write(Reg.SW_MODE, self.sw_mode)
        link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
        link.write(Reg.RAMPMODE, RampMode.POSITION)
        self.verify_ramp(x)

    def verify_ramp(self, x: int) -> None:
        mode, target, sw = self.link.read_many([Reg.RAMPMODE, Reg.XTARGET, Reg.SW_MODE])
        if (mode & 3, signed32(target), sw) != (RampMode.POSITION, x, self.sw_mode):
            raise TmcError(
                f"{self.device.path} ({self.name}): ramp registers read back wrong "
                f"(RAMPMODE={mode}, XTARGET={signed32(target)}, SW_MODE=0x{sw:x})"
            )

    def watch(self, direction: int, stall: bool = False) -> None:
        """Stop switches for the next motion: the one ahead in ``direction`` (+1: REFR,
        -1: REFL, 0: none) stops the motor hard and latches XACTUAL into XLATCH on its active
        edge; ``stall``: stallGuard stops it (sg_stop). Old latches and events are cleared."""
        sw = self._sw_mode_base()
        if direction > 0:
            sw = F.LATCH_R_ACTIVE.put(F.STOP_R_ENABLE.put(sw, 1), 1)
        elif direction < 0:
            sw = F.LATCH_L_ACTIVE.put(F.STOP_L_ENABLE.put(sw, 1), 1)
        if stall:
            sw = F.SG_STOP.put(sw, 1)
        with self.device.session():
            self.link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
            self.link.write(Reg.SW_MODE, sw)
        self.sg_stopped = False

    def status(self) -> DriverStatus:
        """As :meth:`TmcDriver.status`; a stop by stallGuard (seen by the executor) is a stall."""
        status = super().status()
        if self.sg_stopped and not status.stall:
            return DriverStatus(status.fault, stall=True)
        return status

    def _ramps(self, acc: float, dec: float) -> None:
        a, d = self.units.accel(acc), self.units.decel(dec)
        self.link.write(Reg.AMAX, a)
        self.link.write(Reg.A1, a)
        self.link.write(Reg.DMAX, d)
        self.link.write(Reg.D1, d)  # never 0 in positioning mode, even with V1 = 0

    def move_to(self, target: int, speed: float, acc: float, dec: float) -> None:
        """Positioning mode: run a trapezoid to ``target`` (steps)."""
        with self.device.session():
            self._ramps(acc, dec)
            self.link.write(Reg.VMAX, self.units.velocity(speed))
            self.link.write(Reg.RAMPMODE, RampMode.POSITION)
            self.link.write(Reg.XTARGET, target)

    def run(self, direction: int, speed: float, acc: float) -> None:
        """Velocity mode: accelerate with ``acc`` to ``speed`` in ``direction`` (+1/-1)."""
        with self.device.session():
            self.link.write(Reg.AMAX, self.units.accel(acc))
            self.link.write(Reg.VMAX, self.units.velocity(speed))
            mode = RampMode.VELOCITY_POS if direction > 0 else RampMode.VELOCITY_NEG
            self.link.write(Reg.RAMPMODE, mode)

    def stop(self, dec: float | None) -> None:
        """Stop along ``dec`` (steps/s^2), or as hard as the chip can (``None``)."""
        with self.device.session():
            a = self.units.AMAX_MAX if dec is None else self.units.decel(dec)
            state = self.state()
            self.link.write(Reg.AMAX, a)
            self.link.write(Reg.DMAX, a)
            self.link.write(Reg.D1, a)
            self.link.write(Reg.VMAX, 0)  # velocity mode ramps to 0 with AMAX
            mode = RampMode.VELOCITY_POS if state.vactual >= 0 else RampMode.VELOCITY_NEG
            self.link.write(Reg.RAMPMODE, mode)

    def state(self) -> RampState:
        x, v, rs = self.link.read_many([Reg.XACTUAL, Reg.VACTUAL, Reg.RAMP_STAT])
        return RampState(signed32(x), Field(0, 24, signed=True).get(v), rs)

    def position(self) -> int:
        return signed32(self.link.read(Reg.XACTUAL))

    def set_position(self, x: int) -> None:
        """Declare the (standing) motor to be at ``x`` without moving it."""
        with self.device.session():
            self.link.write(Reg.RAMPMODE, RampMode.HOLD)
            self.link.write(Reg.VMAX, 0)
            self.link.write(Reg.XACTUAL, x)
            self.link.write(Reg.XTARGET, x)
            self.link.write(Reg.RAMPMODE, RampMode.POSITION)

    def home_start(self, direction: int, speed: float, acc: float, source: str) -> None:
        """Run toward the reference switch (REFR for +, REFL for -) or until stallGuard stops
        the chip; the switch's active edge latches XACTUAL into XLATCH."""
        with self.device.session():
            self.watch(0 if source == "stall" else direction, stall=source == "stall")
            self.run(direction, speed, acc)

    def home_event(self, state: RampState, direction: int, source: str) -> bool:
        """True when the homing stop happened (the chip stopped the motor itself)."""
        if source == "stall":
            return state.flag(F.EVENT_STOP_SG)
        return state.flag(F.EVENT_STOP_R if direction > 0 else F.EVENT_STOP_L)

    def home_finish(self, source: str) -> int:
        """After the stop: make the trigger point position 0; returns the overshoot (steps).

        The switch latched XACTUAL at its active edge (XLATCH); for a stall, the stop
        position is the reference. Stop switches and sg_stop are disabled again so that
        the motor can leave the switch.
        """
        with self.device.session():
            self.link.write(Reg.VMAX, 0)  # else clearing the stop would start it again
            self.link.write(Reg.RAMPMODE, RampMode.HOLD)
            x, latch = (signed32(v) for v in self.link.read_many([Reg.XACTUAL, Reg.XLATCH]))
            ref = x if source == "stall" else latch
            self.link.write(Reg.SW_MODE, self._sw_mode_base())
            self.link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
            self.set_position(x - ref)
        return x - ref


# ------------------------------------------------------------------------------ the monitor


@dataclass
class _Entry:
    driver: TmcDriver
    period_s: float
    due: float = 0.0


@dataclass
class DriverMonitor:
    """One thread that polls every driver's DRV_STATUS at that driver's rate.

    It owns only its schedule; each driver's poll catches its own SPI errors and turns them
    into a latched fault, and an unexpected exception in one poll is logged and latched as
    a fault of that driver: the thread never dies. ``stop()`` returns within ``join_s``.
    """

    drivers: Sequence[TmcDriver]
    now: Callable[[], float]
    join_s: float = 2.0
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    rounds: int = 0

    def start(self) -> None:
        if self._thread is not None or not self.drivers:
            return
        self._thread = threading.Thread(target=self._run, name="tmc-monitor", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(self.join_s)
            if thread.is_alive():
                log.error("the driver monitor did not stop within %.1f s", self.join_s)

    def poll_due(self, entries: list[_Entry]) -> float:
        """Poll what is due; returns the time until the next poll is due."""
        now = self.now()
        for e in entries:
            if now >= e.due:
                e.due = now + e.period_s
                try:
                    e.driver.poll()
                except Exception as exc:  # a bug must not kill the monitor: latch and go on
                    log.exception("%s: driver poll failed", e.driver.name)
                    e.driver._set_transient(f"internal error in the driver monitor: {exc!r}")
                    e.driver._publish(None)
        self.rounds += 1
        return max(0.0, min(e.due for e in entries) - self.now())

    def _run(self) -> None:
        entries = [_Entry(d, d.settings.poll_ms / 1000.0) for d in self.drivers]
        while not self._stop.is_set():
            wait = self.poll_due(entries)
            self._stop.wait(wait)
