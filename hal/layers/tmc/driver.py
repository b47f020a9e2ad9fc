"""The shared driver of the TMC chips: started, configured and verified, then watched.

:class:`TmcDriver` opens its SPI device, checks the chip's version, writes and verifies its
configuration (``settings.py``), and from then on reads DRV_STATUS for the HAL's
:class:`~motorctl.hal.interfaces.StepperDriver` contract: over-temperature and shorts (and,
while moving, open load) are faults; the stallGuard flag is the motor's stall. It also
reads what ``--probe`` shows (:meth:`TmcDriver.probe`, a :class:`ChipReading`) and the
status's driver figures (:meth:`TmcDriver.stats`). It is a whole TMC2130, or a TMC5160 moved
by STEP/DIR; what differs between the chips is asked of their
:class:`~motorctl.hal.layers.tmc.fields.Chip`. A TMC5160 that runs its own ramp is the
subclass in ``tmc5160.py``. (As Klipper's tmc.py, this module names no chip.)

Threads: a :class:`TmcDriver` is started by the thread that builds the hardware; from then on
:meth:`TmcDriver.poll` runs on the HAL's driver poller's thread only (hal/poller.py, through
:meth:`TmcDriver.refresh`), and any other thread calls :meth:`TmcDriver.status`, which
returns the poller's last result without any I/O (a reference read under a short lock:
never blocks on SPI).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable
from dataclasses import dataclass

from motorctl.hal.interfaces import DriverStatus, StepperDriver
from motorctl.hal.layers.tmc.fields import Chip, F, Field, Reg, decode_spi_status
from motorctl.hal.layers.tmc.link import TmcError, TmcLink, identify
from motorctl.hal.layers.tmc.settings import TmcSettings, register_values
from motorctl.hal.spi import SpiBus, SpiError

log = logging.getLogger("motorctl.tmc")


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
        out = ["over-temperature (ot)"] if self.flag(F.OT) else []
        return out + [text for f, text in self.chip.shorts if self.flag(f)]

    @property
    def shorted(self) -> bool:
        return any(self.flag(f) for f, _ in self.chip.shorts)

    def open_load(self) -> list[str]:
        """Open-load flags; the datasheet says they are valid only in slow motion."""
        return [
            t
            for f, t in (
                (F.OLA, "open load on phase A (ola)"),
                (F.OLB, "open load on phase B (olb)"),
            )
            if self.flag(f)
        ]

    def describe(self) -> str:
        """All flags and values, as ``--probe`` prints them."""
        on = [name for name, f in self.chip.flags if self.flag(f)]
        return (
            f"DRV_STATUS=0x{self.raw:08x} SG_RESULT={F.SG_RESULT.get(self.raw)} "
            f"CS_ACTUAL={F.CS_ACTUAL.get(self.raw)} flags: {' '.join(on) or 'none'}"
        )


@dataclass(frozen=True)
class ChipReading:
    """What ``--probe`` read of one chip, writing nothing: IOIN, DRV_STATUS and the SPI
    status byte, the chip it was configured as and the one whose version IOIN holds
    (``found``; None: a chip the layer does not know)."""

    name: str
    path: str
    configured: Chip
    found: Chip | None
    version: int
    ioin: int
    drv_status: int
    spi_status: int

    @property
    def matches(self) -> bool:
        """The chip that answers is the one configured."""
        return self.found is self.configured

    @property
    def sd_mode(self) -> int | None:
        """IOIN's SD_MODE pin (1: STEP/DIR) on a chip that has one, else None."""
        chip = self.found or self.configured
        return None if chip.sd_mode is None else chip.sd_mode.get(self.ioin)

    def lines(self) -> list[str]:
        """The reading in words, decoded as the chip that answers (``--probe``)."""
        found = self.found.name if self.found else f"unknown chip (version 0x{self.version:02x})"
        verdict = "ok" if self.matches else f"MISMATCH: configured {self.configured.name}"
        chip = self.found or self.configured
        spi = " ".join(decode_spi_status(self.spi_status, chip)) or "none"
        out = [
            f"{self.name}: {self.path}: {found} (IOIN=0x{self.ioin:08x}) {verdict}",
            f"  {DrvStatus(self.drv_status, chip).describe()}",
            f"  SPI status: {spi}",
        ]
        if self.sd_mode is not None:
            what = "external STEP/DIR" if self.sd_mode else "internal ramp generator"
            out.append(f"  SD_MODE={self.sd_mode} ({what})")
        return out


class TmcDriver(StepperDriver):
    """One TMC2130 or TMC5160: started once, polled by the driver poller, read by the rest.

    ``known``: the other chips to name when one of them answers where ``settings.chip`` was
    configured (the layer passes every chip it knows: ``chips.CHIPS``)."""

    def __init__(
        self, name: str, device: SpiBus, settings: TmcSettings, known: Iterable[Chip] = ()
    ) -> None:
        self.name = name
        self.settings = settings
        self.chip = settings.chip
        self.known = {c.version: c for c in (*known, self.chip)}
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
            other = self.known.get(version)
            found = f"a {other.name}" if other else f"an unknown chip (version 0x{version:02x})"
            raise TmcError(
                f"{self.device.path} ({self.name}): configured as {self.chip.name} "
                f"(IOIN version 0x{self.chip.version:02x}) but found {found}; set "
                f'driver = "{other.name.lower() if other else "..."}" or check which '
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
                    f"{self.device.path} ({self.name}): {self.chip.register_name(addr)} reads back "
                    f"0x{value:08x}, 0x{self.regs[addr]:08x} was written; the chip may have "
                    "been reset (check VM) or the SPI wiring is unreliable"
                )

    def clear_gstat(self) -> int:
        """Read GSTAT (clears it on the TMC2130) and write 1s back (clears it on the TMC5160)."""
        gstat = self.link.read(Reg.GSTAT)
        if self.chip.gstat_write_clears:
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

    # -- any thread ------------------------------------------------------------------
    def status(self) -> DriverStatus:
        """The latest poll's verdict, without I/O. A transient fault is then forgotten
        once the chip is healthy again (so StopMove can clear it)."""
        with self._lock:
            if self._transient_out:  # the reader sees it now: forget it from the next poll
                self._transient = None
                self._transient_out = False
            return self._status

    # -- the driver poller's thread -------------------------------------------------------
    def refresh(self) -> DriverStatus:
        """A poll, read as the motors read it (:meth:`status`): the driver poller's call,
        which hands a fault or a stall on to the motion engine."""
        self.poll()
        return self.status()

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
            self._disabled = (
                ", ".join(drv.faults()) + " - driver disabled; fix the wiring and restart motorctld"
            )
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
        if self.chip.uv_cp and F.UV_CP.get(gstat):
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

    def probe(self) -> ChipReading:
        """What ``--probe`` shows of the chip: its version, IOIN and DRV_STATUS, read only
        (not GSTAT, which a TMC2130 clears on reading). The device must be open; a chip
        that does not answer raises TmcError, a failed transfer SpiError."""
        version = identify(self.link)
        ioin, drv_raw = self.link.read_many([Reg.IOIN, Reg.DRV_STATUS])
        return ChipReading(
            self.name,
            self.device.path,
            self.chip,
            self.known.get(version),
            version,
            ioin,
            drv_raw,
            self.link.last_status,
        )
