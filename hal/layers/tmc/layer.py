"""The TMC layer (:class:`TmcLayer`, hal/contract.py): TMC2130/TMC5160 drivers over spidev,
attached to hardware that any backend built, and probed.

A motor's STEP/DIR lines, end stops and pins come from the hardware backend (``mock``,
``gpiod``); its driver chip, when the config names one, is opened here, on the machine's
SPI bus of its device node (``Hardware.spi``, hal/spi.py): each chip is identified,
configured and verified before anything moves, and registered with the HAL's driver poller
(``Hardware.poller``, hal/poller.py), which reads its DRV_STATUS from then on. py-spidev is
imported only when a driver is configured (by hal/spi.py). The registry
(``hal/registry.py``, ``LAYERS``) attaches and probes it when its declaration
(``config.py``) says the config gives a motor a driver.

Threads: :meth:`TmcLayer.attach` runs on the thread that opens the hardware; afterwards the
drivers are polled on the driver poller's thread and read lock-free by the others. The
closer registered in ``Hardware.closers`` (run after the Hardware stopped its poller)
leaves each driver disabled (TOFF = 0) when so configured. ``--probe`` reads on the
probing thread.
"""

from __future__ import annotations

import logging

from motorctl.hal.contract import Layer, ProbeReport, ProblemKind
from motorctl.hal.interfaces import Clock, HalError, Hardware
from motorctl.hal.layers.tmc.config import CHIPS, SpidevConfig
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.link import TmcError
from motorctl.hal.layers.tmc.settings import TmcSpec
from motorctl.hal.layers.tmc.tmc5160 import RefSwitches, Tmc5160
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import SpiAddress, SpiBuses, SpiFactory, SpiSettings, spidev_factory

log = logging.getLogger("motorctl.tmc")


def open_driver(
    name: str,
    spec: TmcSpec,
    buses: SpiBuses,
    factory: SpiFactory | None,
    layer: SpidevConfig | None = None,
) -> TmcDriver:
    """A driver object for ``spec`` (not started) on its device node's bus of ``buses``
    (``factory``: py-spidev's API to open it with; None: py-spidev); ValueError for an
    impossible setting. ``layer``: the ``[spidev]`` settings (a ramp chip's poll periods;
    None: the driver's defaults, the keys' defaults too)."""
    try:
        address = SpiAddress.parse(spec.spi)
    except ValueError as exc:
        raise TmcError(f"{name}: {exc}") from exc
    chip = spec.settings.chip.name
    settings = SpiSettings(spec.spi_speed_hz)  # mode 3, 8-bit words: both chips' SPI
    device = buses.bus(address, settings, f"{name} ({chip})", factory)
    known = CHIPS.values()
    if spec.ramp:
        switches = RefSwitches(spec.ref_left_active_low, spec.ref_right_active_low)
        if layer is None:
            return Tmc5160(name, device, spec.settings, switches, known=known)
        return Tmc5160(
            name,
            device,
            spec.settings,
            switches,
            poll_s=layer.ramp_poll_ms / 1000,
            idle_poll_s=layer.ramp_idle_poll_ms / 1000,
            known=known,
        )
    return TmcDriver(name, device, spec.settings, known)


def attach_drivers(
    hw: Hardware, spec: HardwareSpec, factory: SpiFactory | None = None
) -> list[TmcDriver]:
    """Open, check and configure every driver the spec's axes name (on the machine's SPI
    buses), put each in place of its motor's driver and register it with the machine's
    driver poller. On any error the drivers already opened are closed again and a
    TmcError/SpiError (HalError) names the device and the fix."""
    specs = [a.driver if isinstance(a.driver, TmcSpec) else None for a in spec.axes]
    if not any(specs):
        return []
    if len(specs) > len(hw.steppers):
        raise TmcError(f"{len(specs)} drivers configured for {len(hw.steppers)} motors")
    names = [a.name or f"motor {i}" for i, a in enumerate(spec.axes)]
    layer = spec.sections.get(SpidevConfig)
    started: list[tuple[int, TmcDriver, TmcSpec]] = []
    try:
        for i, tmc in enumerate(specs):
            if tmc is None:
                continue
            driver = open_driver(names[i], tmc, hw.spi, factory, layer)
            driver.start()
            started.append((i, driver, tmc))
    except BaseException:
        for _, driver, _tmc in started:
            driver.device.close()
        raise
    for i, driver, _tmc in started:
        hw.steppers[i].driver = driver
        hw.poller.watch(driver, f"{driver.name} ({driver.chip.name} on {driver.device.path})")
    drivers = [d for _, d, _ in started]

    def close() -> None:  # the Hardware's close stopped the poller first
        for _, driver, tmc in started:
            if tmc.disable_at_exit:
                driver.close()
            else:
                driver.device.close()

    hw.closers.append(close)
    log.info(
        "drivers: %s", ", ".join(f"{d.name} {d.chip.name} on {d.device.path}" for d in drivers)
    )
    return drivers


def _probe_one(
    report: ProbeReport, name: str, tmc: TmcSpec, buses: SpiBuses, factory: SpiFactory | None
) -> list[str]:
    """One configured driver's lines for ``--probe``; its problems go to ``report``."""
    try:
        driver = open_driver(name, tmc, buses, factory)
        driver.device.open()
    except (HalError, ValueError) as exc:
        report.problem(f"{name}: {exc}")
        return []
    try:
        reading = driver.probe()
    except HalError as exc:  # nothing answers, or a transfer failed
        report.problem(f"{name}: {exc}")
        return [f"{name}: {exc}"]
    finally:
        driver.device.close()
    lines = reading.lines()
    if not reading.matches:
        report.problem(lines[0], ProblemKind.MISMATCH)
    elif tmc.ramp and reading.sd_mode:
        report.problem(
            f"{name}: configured for the TMC5160's ramp generator but its SD_MODE pin is "
            "high (STEP/DIR); tie SD_MODE to GND",
            ProblemKind.MISMATCH,
        )
    return lines


class TmcLayer(Layer):
    """TMC2130/TMC5160 driver chips over SPI. ``factory``: py-spidev's ``SpiDev`` or a
    stand-in with its API (tests); None: py-spidev, imported when a driver is opened."""

    name = "tmc"

    def __init__(self, factory: SpiFactory | None = None) -> None:
        self.factory = factory

    def attach(self, hw: Hardware, spec: HardwareSpec, clock: Clock) -> None:
        del clock  # the poller reads the Hardware's
        attach_drivers(hw, spec, self.factory)

    def probe(
        self,
        spec: HardwareSpec,
        clock: Clock,
        report: ProbeReport,
        spi_factory: SpiFactory | None = None,
    ) -> None:
        """Each configured driver's chip and version, DRV_STATUS decoded, SPI status; reads
        registers only (nothing is written, nothing moves). Problems go to the report: a
        device that is missing or does not answer, another chip than configured, a ramp
        chip whose SD_MODE is high."""
        del clock, spi_factory  # no backend simulates a TMC chip
        configured = [
            (a.name or f"motor {i}", a.driver)
            for i, a in enumerate(spec.axes)
            if isinstance(a.driver, TmcSpec)
        ]
        if not configured:
            return
        try:
            factory = self.factory or spidev_factory()
        except HalError as exc:
            report.problem(str(exc))
            return
        buses = SpiBuses()
        lines: list[str] = []
        for name, tmc in configured:
            lines += _probe_one(report, name, tmc, buses, factory)
        report.add("SPI stepper drivers", lines)
