"""A TMC2130 or TMC5160 as a stepper driver: started, configured and verified, then watched.

:class:`TmcDriver` opens its SPI device, checks the chip's version, writes and verifies its
configuration (``settings.py``), and from then on reads DRV_STATUS for the HAL's
:class:`~motorctl.hal.interfaces.StepperDriver` contract: over-temperature and shorts (and,
while moving, open load) are faults; the stallGuard flag is the motor's stall. It also
answers ``--probe`` and the status's driver figures (:meth:`TmcDriver.stats`). A TMC5160
that runs its own ramp is the subclass in ``ramp.py``.

Threads: a :class:`TmcDriver` is started by the thread that builds the hardware; from then on
:meth:`TmcDriver.poll` runs in the monitor thread only (``monitor.py``), and the step thread
calls :meth:`TmcDriver.status`, which returns the monitor's last result without any I/O
(a reference read under a short lock: never blocks on SPI).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable
from dataclasses import dataclass

from motorctl.hal.interfaces import DriverStatus, StepperDriver
from motorctl.hal.layers.tmc import tmc5160
from motorctl.hal.layers.tmc.fields import Chip, F, Field, Reg, decode_spi_status
from motorctl.hal.layers.tmc.link import REG_NAMES, TmcError, TmcLink, identify
from motorctl.hal.layers.tmc.settings import CHIP_BY_VERSION, TmcSettings, register_values
from motorctl.hal.layers.tmc.spi import SpiDevice, SpiError
from motorctl.hal.layers.tmc.tmc5160 import TMC5160

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
        out = []
        if self.flag(F.OT):
            out.append("over-temperature (ot)")
        for f, text in (
            (F.S2GA, "short to ground on phase A (s2ga)"),
            (F.S2GB, "short to ground on phase B (s2gb)"),
        ):
            if self.flag(f):
                out.append(text)
        if self.chip.has_s2vs:
            for f, text in (
                (tmc5160.F.S2VSA, "short to supply on phase A (s2vsa)"),
                (tmc5160.F.S2VSB, "short to supply on phase B (s2vsb)"),
            ):
                if self.flag(f):
                    out.append(text)
        return out

    @property
    def shorted(self) -> bool:
        flags = [F.S2GA, F.S2GB]
        if self.chip.has_s2vs:
            flags += [tmc5160.F.S2VSA, tmc5160.F.S2VSB]
        return any(self.flag(f) for f in flags)

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
        names = ["stst", "olb", "ola", "s2gb", "s2ga", "otpw", "ot", "stallGuard", "fsactive"]
        fields = [F.STST, F.OLB, F.OLA, F.S2GB, F.S2GA, F.OTPW, F.OT, F.STALLGUARD, F.FSACTIVE]
        if self.chip.has_s2vs:
            names += ["stealth", "s2vsb", "s2vsa"]
            fields += [tmc5160.F.STEALTH, tmc5160.F.S2VSB, tmc5160.F.S2VSA]
        on = [n for n, f in zip(names, fields, strict=True) if self.flag(f)]
        return (
            f"DRV_STATUS=0x{self.raw:08x} SG_RESULT={F.SG_RESULT.get(self.raw)} "
            f"CS_ACTUAL={F.CS_ACTUAL.get(self.raw)} flags: {' '.join(on) or 'none'}"
        )


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
            f"  SPI status: {' '.join(decode_spi_status(self.link.last_status, chip)) or 'none'}",
        ]
        if chip is TMC5160:
            sd_mode = tmc5160.F.SD_MODE.get(ioin)
            lines.append(
                f"  SD_MODE={sd_mode} "
                f"({'external STEP/DIR' if sd_mode else 'internal ramp generator'})"
            )
        return lines
