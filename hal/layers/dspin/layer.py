"""The dSPIN layer (:class:`DspinLayer`, hal/contract.py): ST's L6470, L6472, L6480 and
powerSTEP01 in daisy chains over spidev, attached to hardware any backend built, and probed.

Each chain (the motors whose ``[motors.dspin] spi`` is one device node) is opened on the
machine's SPI bus of that node (``Hardware.spi``, hal/spi.py; mode 3), each chip checked
and set up (``driver.py``) before anything moves, put in place of its motor's driver (the
HAL's RampDriver: the chip-ramp executor moves it) and the chain registered with the HAL's
driver poller (``Hardware.poller``) as one poll: one GetStatus exchange for every chip.
The nodes are opened with ``Hardware.spi_factory`` where the backend simulates them (the
mock's chains), else py-spidev (imported only then, by hal/spi.py).

Threads: :meth:`DspinLayer.attach` runs on the thread that opens the hardware; afterwards
as ``driver.py`` says. The closer registered in ``Hardware.closers`` (run after the poller
stopped) leaves each chip in HiZ (``hiz_at_exit``) or stopped. ``--probe`` reads on the
probing thread.
"""

from __future__ import annotations

import logging

from motorctl.hal.contract import Layer, ProbeReport, ProblemKind
from motorctl.hal.dspin.chips import CHIPS
from motorctl.hal.dspin.commands import get_param
from motorctl.hal.dspin.spec import DspinSpec, chains
from motorctl.hal.dspin.status import Status
from motorctl.hal.interfaces import Clock, EdgeInputs, HalError, Hardware
from motorctl.hal.layers.dspin.config import DspinConfig
from motorctl.hal.layers.dspin.driver import Chain, DspinDriver, DspinError
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import SpiAddress, SpiBuses, SpiFactory, SpiSettings, spidev_factory

log = logging.getLogger("motorctl.dspin")


def open_chain(
    node: str,
    members: list[tuple[int, DspinSpec]],
    names: list[str],
    buses: SpiBuses,
    factory: SpiFactory | None,
    layer: DspinConfig | None,
) -> Chain:
    """The chain on ``node`` (its bus made, not opened) with a driver per member."""
    try:
        address = SpiAddress.parse(node)
    except ValueError as exc:
        raise DspinError(f"{names[members[0][0]]}: {exc}") from exc
    settings = SpiSettings(members[0][1].spi_speed_hz)  # mode 3, 8-bit words
    bus = buses.bus(address, settings, f"a dSPIN chain of {len(members)}", factory)
    chain = Chain(bus, len(members))
    poll_s = (layer.ramp_poll_ms if layer else 5.0) / 1000
    idle_s = (layer.ramp_idle_poll_ms if layer else 50.0) / 1000
    for i, spec in members:
        chain.drivers.append(DspinDriver(names[i], spec, chain, poll_s, idle_s))
    return chain


def wire_lines(
    hw: Hardware, members: list[tuple[int, DspinSpec]], output: str
) -> list[tuple[EdgeInputs, set[int]]]:
    """Each line a chain's chips wire their ``output`` (``flag``, ``busy``) to, opened as
    an edge input of its own (chips sharing a line: wired-OR) with the chain positions on
    it; closed with the Hardware."""
    lines: dict[str, tuple[str, set[int]]] = {}
    for i, spec in members:
        line = getattr(spec, output)
        if line:
            lines.setdefault(line, (f"motors[{i}].dspin.{output}", set()))[1].add(spec.position)
    out: list[tuple[EdgeInputs, set[int]]] = []
    for line, (use, on) in lines.items():
        inputs = hw.open_alert_lines([(use, line)])
        hw.closers.append(inputs.close)
        out.append((inputs, on))
    return out


def attach_chains(
    hw: Hardware, spec: HardwareSpec, factory: SpiFactory | None = None
) -> list[DspinDriver]:
    """Open and set up every chain the spec's axes name, put each chip in place of its
    motor's driver and register each chain with the machine's driver poller. On any error
    the nodes already opened are closed again and a DspinError/SpiError (HalError) names
    the chip and the fix."""
    found = chains(spec)
    if not found:
        return []
    names = [a.name or f"motor {i}" for i, a in enumerate(spec.axes)]
    layer = spec.sections.get(DspinConfig)
    opened: list[Chain] = []
    try:
        for node, members in found.items():
            chain = open_chain(node, members, names, hw.spi, factory, layer)
            chain.bus.open()
            opened.append(chain)
            for driver in chain.drivers:
                driver.start()
    except BaseException:
        for chain in opened:
            chain.bus.close()
        raise
    drivers: list[DspinDriver] = []
    for (node, members), chain in zip(found.items(), opened, strict=True):
        for (i, _), driver in zip(members, chain.drivers, strict=True):
            hw.poller.forget(hw.steppers[i].driver)  # a backend's stand-in: not read now
            hw.steppers[i].driver = driver
        entry = hw.poller.add(f"dSPIN chain on {node}", chain.poll, chain.drivers)
        for inputs, on in wire_lines(hw, members, "flag"):
            alert = hw.poller.alert(entry, inputs, 0)  # FLAG falls: the chain read at once
            for driver in chain.drivers:
                if driver.position in on:
                    driver.flag_alert = alert
        for inputs, on in wire_lines(hw, members, "busy"):
            for driver in chain.drivers:
                if driver.position in on:
                    driver.busy_line = inputs
        drivers += chain.drivers

    def close() -> None:  # the Hardware's close stopped the poller first
        for chain in opened:
            for driver in chain.drivers:
                driver.close()
            chain.bus.close()

    hw.closers.append(close)
    log.info(
        "dSPIN: %s",
        ", ".join(f"{d.name} {d.chip.name} #{d.position} on {d.chain.bus.path}" for d in drivers),
    )
    return drivers


def probe_chain(chain: Chain) -> tuple[list[str], list[str]]:
    """What ``--probe`` shows of a chain: each chip's CONFIG (which model it is) and STATUS
    read with GetParam (which clears nothing); and the mismatches."""
    lines: list[str] = []
    problems: list[str] = []
    for d in chain.drivers:
        got = chain.exchange({d.position: get_param(d.chip.config)})[d.position]
        word = chain.exchange({d.position: get_param(d.chip.status_register)})[d.position]
        st = Status(d.chip.status, word)
        kinds = [c.name for c in CHIPS.values() if c.config.addr == d.chip.config.addr]
        verdict = d.chip.name if got == d.chip.config.reset else "not the configured chip"
        lines.append(
            f"{d.name}: #{d.position} on {chain.bus.path}: configured {d.chip.name}, CONFIG "
            f"0x{got:04X} ({verdict}); STATUS {st}"
        )
        if got != d.chip.config.reset:
            problems.append(
                f"{d.name}: the chip at position {d.position} on {chain.bus.path} reads CONFIG "
                f"0x{got:04X} at 0x{d.chip.config.addr:02X}, where a {' or '.join(kinds)} "
                f"reads 0x{d.chip.config.reset:04X} after reset"
            )
    return lines, problems


class DspinLayer(Layer):
    """ST dSPIN chips in daisy chains over SPI. ``factory``: py-spidev's ``SpiDev`` or a
    stand-in with its API (tests); None: the chains the backend simulates (the Hardware's
    ``spi_factory``; for ``--probe`` its ``simulated_spi``), else py-spidev."""

    name = "dspin"

    def __init__(self, factory: SpiFactory | None = None) -> None:
        self.factory = factory

    def attach(self, hw: Hardware, spec: HardwareSpec, clock: Clock) -> None:
        del clock  # the poller reads the Hardware's
        attach_chains(hw, spec, self.factory or hw.spi_factory)

    def probe(
        self,
        spec: HardwareSpec,
        clock: Clock,
        report: ProbeReport,
        spi_factory: SpiFactory | None = None,
    ) -> None:
        """Each chain's chips: CONFIG against the configured model, STATUS decoded; reads
        registers only (nothing is written, nothing moves, no flag is cleared)."""
        del clock
        found = chains(spec)
        if not found:
            return
        try:
            factory = self.factory or spi_factory or spidev_factory()
        except HalError as exc:
            report.problem(str(exc))
            return
        names = [a.name or f"motor {i}" for i, a in enumerate(spec.axes)]
        buses = SpiBuses()
        lines: list[str] = []
        for node, members in found.items():
            try:
                chain = open_chain(node, members, names, buses, factory, None)
                chain.bus.open()
            except HalError as exc:
                report.problem(f"dSPIN chain on {node}: {exc}")
                continue
            try:
                found_lines, problems = probe_chain(chain)
            except HalError as exc:
                report.problem(f"dSPIN chain on {node}: {exc}")
                continue
            finally:
                chain.bus.close()
            lines += found_lines
            for p in problems:
                report.problem(p, ProblemKind.MISMATCH)
        report.add("dSPIN drivers", lines)
