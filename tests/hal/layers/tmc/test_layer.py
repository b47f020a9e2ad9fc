"""The TMC layer (layer.py) as the registry uses it: drivers attached to the mock's hardware
and monitored, closed again on any error, py-spidev's absence named, and ``--probe``'s
readings with their problems as data."""

from __future__ import annotations

import sys
import time

import pytest

from motorctl.hal.contract import ProbeReport, ProblemKind
from motorctl.hal.interfaces import HalError, MonotonicClock
from motorctl.hal.layers.tmc.config import TmcDeclaration
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.layer import TmcLayer
from motorctl.hal.layers.tmc.link import TmcError
from motorctl.hal.layers.tmc.settings import TmcSettings, TmcSpec
from motorctl.hal.spec import AxisSpec, HardwareSpec
from tests.support import tmc_model as tm
from tests.support.mock_factory import MockFactory
from tests.support.spi_bench import S2130, S5160, SpiBench


def spec_with(*drivers: TmcSpec | None) -> HardwareSpec:
    return HardwareSpec(tuple(AxisSpec(name=f"m{i}", driver=d) for i, d in enumerate(drivers)))


def test_open_hardware_starts_configured_drivers_and_registers_them_with_the_poller(
    spi_bench: SpiBench, mock_factory: MockFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = spi_bench.chip("tmc2130", cs=1)
    spi_bench.as_spidev_module(monkeypatch)
    spec = spec_with(None, TmcSpec("/dev/spidev0.1", TmcSettings()))
    hw = mock_factory.hardware(spec, MonotonicClock())
    try:
        drv = hw.steppers[1].driver
        assert isinstance(drv, TmcDriver) and drv.name == "m1"
        assert not isinstance(hw.steppers[0].driver, TmcDriver)
        assert model.regs[tm.A_CHOPCONF] & 0xF == 3  # configured, energised
        assert [e.drivers for e in hw.poller.entries if drv in e.drivers] == [(drv,)]
        assert [b.path for b in hw.spi] == ["/dev/spidev0.1"]  # the machine's bus of its node
        hw.poller.period_s = 0.001
        hw.poller.start()  # what the motion engine does when it starts
        deadline = time.monotonic() + 10.0
        while drv.polls < 3:
            assert time.monotonic() < deadline, "the poller did not read the chip within 10 s"
            time.sleep(0.005)
    finally:
        hw.close()
    polls = drv.polls
    assert model.regs[tm.A_CHOPCONF] & 0xF == 0  # disabled at exit
    assert not hw.poller.running
    time.sleep(0.02)
    assert drv.polls == polls  # the poller stopped before the chip was closed


def test_a_failing_driver_closes_the_ones_already_opened(
    spi_bench: SpiBench, mock_factory: MockFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    spi_bench.chip("tmc2130", cs=0)
    spi_bench.chip("tmc5160", cs=1)
    spi_bench.as_spidev_module(monkeypatch)
    good, wrong = TmcSpec("/dev/spidev0.0", S2130), TmcSpec("/dev/spidev0.1", S2130)
    with pytest.raises(TmcError, match=r"m1.*found a TMC5160"):
        mock_factory.hardware(spec_with(good, wrong))
    assert all(dev._fd == -1 for dev in spi_bench.kernel.opened)  # nothing left open


def test_without_py_spidev_a_configured_driver_says_how_to_install_it(
    mock_factory: MockFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "spidev", None)  # import spidev -> ImportError
    with pytest.raises(HalError, match=r"pip install spidev"):
        mock_factory.hardware(spec_with(TmcSpec("/dev/spidev0.0", S2130)))
    mock_factory.hardware(spec_with(None))  # no driver: no spidev needed


def test_probe_reports_chip_versions_and_drv_status_without_writing(spi_bench: SpiBench) -> None:
    ok = spi_bench.chip("tmc2130", cs=0)
    ok.faults.add(tm.OTPW)
    spi_bench.chip("tmc2130", cs=1)  # configured as a TMC5160 below: a mismatch
    spec = spec_with(
        TmcSpec("/dev/spidev0.0", S2130),
        TmcSpec("/dev/spidev0.1", S5160),
        TmcSpec("/dev/spidev0.2", S2130),  # no such device
    )
    report = ProbeReport()
    TmcLayer(spi_bench.kernel.factory()).probe(spec, spi_bench.clock, report)
    ((title, lines),) = report.sections
    assert title == "SPI stepper drivers"
    text = "\n".join(lines)
    assert "m0: /dev/spidev0.0: TMC2130 (IOIN=0x11000040) ok" in text
    assert "flags: stst otpw" in text and "CS_ACTUAL=" in text
    assert "reset_flag" in text  # the SPI status byte, decoded
    assert "m1: /dev/spidev0.1: TMC2130" in text and "MISMATCH: configured TMC5160" in text
    mismatch, missing = report.problems
    assert mismatch.kind is ProblemKind.MISMATCH and mismatch.text.startswith("m1: ")
    assert missing.kind is ProblemKind.DEVICE and "/dev/spidev0.2 does not exist" in missing.text
    assert all(not tx[0] & 0x80 for tx, _ in ok.log)  # reads only
    assert ok.gstat & 1  # GSTAT untouched


@pytest.mark.parametrize(
    ("chip", "sd_mode", "kind", "says"),
    [
        ("tmc5160", 1, ProblemKind.MISMATCH, "SD_MODE pin is high (STEP/DIR); tie SD_MODE to GND"),
        ("tmc5160", 0, None, ""),
        ("dead", 0, ProblemKind.DEVICE, "m0: /dev/spidev0.0: no driver chip answers"),
    ],
)
def test_probe_of_a_ramp_chip_names_what_keeps_it_from_running_its_ramp(
    spi_bench: SpiBench, chip: str, sd_mode: int, kind: ProblemKind | None, says: str
) -> None:
    spi_bench.chip("tmc2130" if chip == "dead" else chip, sd_mode=sd_mode, dead=chip == "dead")
    report = ProbeReport()
    spec = spec_with(TmcSpec("/dev/spidev0.0", S5160, ramp=True))
    TmcLayer(spi_bench.kernel.factory()).probe(spec, spi_bench.clock, report)
    assert [p.kind for p in report.problems] == ([] if kind is None else [kind])
    assert all(says in p.text for p in report.problems)
    ((_, lines),) = report.sections
    if chip == "dead":
        assert lines == [report.problems[0].text]  # said where the chip would be, too
    else:
        assert f"SD_MODE={sd_mode}" in lines[-1]


def test_the_layer_applies_to_a_spec_with_a_tmc_chip_only() -> None:
    declaration = TmcDeclaration()
    assert declaration.applies(spec_with(None, TmcSpec("/dev/spidev0.1", S2130)))
    assert not declaration.applies(spec_with(None, None))
