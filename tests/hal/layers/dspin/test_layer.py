"""The dSPIN layer (config.py, driver.py, layer.py) as the registry uses it: a config's
``[motors.dspin]`` checked key by key, each chain of the mock world's chip models opened and
set up by the datasheet's sequence, its chips read by the HAL's driver poller in one
exchange per chain, their faults handed to the motors as a driver fault (E4), and
``--probe``'s readings."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal import registry
from motorctl.hal.backends.mock.dspin_chain import DspinChain
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.contract import ProbeReport, ProblemKind
from motorctl.hal.dspin.chips import CHIPS
from motorctl.hal.dspin.spec import DspinSpec
from motorctl.hal.interfaces import Hardware, VirtualClock
from motorctl.hal.layers.dspin.driver import ALARMS_BUT_SWITCH, DspinDriver, DspinError
from motorctl.hal.layers.dspin.layer import DspinLayer
from motorctl.hal.spec import HardwareSpec
from motorctl.schema import ConfigError

CHAIN = """\
[[motors]]
name = "x"
  [motors.dspin]
  driver = "l6470"
  spi = "/dev/spidev0.1"
  kval_run = 60
  microsteps = 8
[[motors]]
name = "y"
  [motors.dspin]
  driver = "l6480"
  spi = "/dev/spidev0.1"
  position = 1
[[motors]]
name = "z"
  [motors.dspin]
  driver = "powerstep01-current"
  spi = "/dev/spidev0.1"
  position = 2
  tval_run = 100
"""


def spec_of(text: str) -> HardwareSpec:
    return hardware_spec(parse_config(text, "test.toml"))


def error_of(text: str) -> str:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "test.toml")
    return str(info.value)


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (("position = 2", "position = 3"), "motors[2].dspin.position = 3: the chain on "),
        (("position = 2", "position = 1"), "motors[2].dspin.position = 1: also the position of"),
        (("microsteps = 8", "microsteps = 6"), "motors[0].dspin.microsteps = 6: the L6470 cannot"),
        (("tval_run = 100", "microsteps = 32"), "powerSTEP01 (current mode) cannot do 32"),
        (("kval_run = 60", "ocd_th = 20"), "motors[0].dspin.ocd_th = 20: the L6470's OCD_TH is 4"),
        (
            ("position = 1\n", "position = 1\n  spi_speed_hz = 2000000\n"),
            "motors[1].dspin.spi_speed_hz = 2000000: motors[0] on the same chain",
        ),
        (('driver = "l6480"', 'driver = "l6666"'), "motors[1].dspin.driver"),
        (
            ('name = "y"\n', 'name = "y"\n[motors.homing]\nsource = "stall"\n'),
            'motors[1].homing.source = "stall": [motors.dspin] switch = "min": the switch on '
            "the chip's SW input would stop the run before the motor stalls",
        ),
        (
            ('name = "x"\n', 'name = "x"\nsoft_limit_min = -3000000\nsoft_limit_max = 10\n'),
            "motors[0].soft_limit_min = -3000000: beyond the dSPIN's ABS_POS",
        ),
    ],
)
def test_a_config_the_chips_cannot_take_is_refused_naming_the_key(
    change: tuple[str, str], says: str
) -> None:
    assert says in error_of(CHAIN.replace(*change, 1))


def test_stall_homing_needs_the_chips_stall_detection() -> None:
    text = CHAIN.replace('driver = "l6470"', 'driver = "l6472"\n  switch = "none"', 1)
    text = text.replace('name = "x"\n', 'name = "x"\n[motors.homing]\nsource = "stall"\n', 1)
    assert 'motors[0].homing.source = "stall": the L6472 has no stall detection' in error_of(text)
    parse_config(text.replace('"l6472"', '"l6470"'), "t.toml")  # an L6470 has it


def test_a_motor_has_one_driver_chip() -> None:
    text = CHAIN.replace("  kval_run = 60\n", '  [motors.tmc]\n  spi = "/dev/spidev0.0"\n', 1)
    assert "motors[0].dspin" in error_of(text) and "[motors.tmc]" in error_of(text)


def test_the_spec_carries_each_chips_registers_and_runs_its_own_ramp() -> None:
    spec = spec_of(CHAIN)
    assert spec.stepped() == ()  # no STEP/DIR: the chips move the motors
    x, y, z = (a.driver for a in spec.axes)
    assert isinstance(x, DspinSpec) and dict(x.registers)["KVAL_RUN"] == 60 and x.microsteps == 8
    assert isinstance(y, DspinSpec) and "STALL_TH" in dict(y.registers)
    assert isinstance(z, DspinSpec) and dict(z.registers)["TVAL_RUN"] == 100


@pytest.fixture
def hw() -> Iterator[Hardware]:
    clock = VirtualClock()
    hw = registry.open_hardware("mock", spec_of(CHAIN), clock)
    yield hw
    hw.close()


def chips_of(hw: Hardware) -> list[DspinChip]:
    nodes = world_of(hw).spi_nodes
    assert nodes is not None
    return [m.chip for m in nodes.chains[(0, 1)].members]


def test_each_chip_is_set_up_from_the_config_at_start(hw: Hardware) -> None:
    drivers = [s.driver for s in hw.steppers]
    assert all(isinstance(d, DspinDriver) for d in drivers)
    x, y, z = chips_of(hw)
    assert (
        x.microsteps == 8 and x.regs["KVAL_RUN"] == 60 and x.regs["ALARM_EN"] == ALARMS_BUT_SWITCH
    )
    assert y.microsteps == 16 and y.regs["KVAL_RUN"] == 41
    assert z.chip is CHIPS["powerstep01-current"] and z.regs["TVAL_RUN"] == 100
    assert all(c.hiz for c in (x, y, z))  # set up in HiZ; the first motion energises them
    assert not any(c.latched for c in (x, y, z))  # the power-up UVLO read and cleared
    # one poll entry for the chain: every chip read in one exchange
    entries = [e for e in hw.poller.entries if drivers[0] in e.drivers]
    assert [e.drivers for e in entries] == [tuple(drivers)]


def test_the_start_follows_the_datasheet_byte_by_byte(hw: Hardware) -> None:
    nodes = world_of(hw).spi_nodes
    assert nodes is not None
    sent = [out for out, _ in nodes.chains[(0, 1)].chain.transfers]
    # chip 0 (x, at MOSI) is the last byte of each transfer: GetStatus, NOP, NOP first
    assert sent[:3] == [bytes([0, 0, 0xD0]), bytes(3), bytes(3)]
    # then GetParam(CONFIG) = 0x38 (CONFIG at 0x18), its two bytes back
    assert sent[3] == bytes([0, 0, 0x38])
    # then HardHiZ (0xA8), SetParam(STEP_MODE) = 0x16 with STEP_SEL 3 (1/8)
    assert sent[6:8] == [bytes([0, 0, 0xA8]), bytes([0, 0, 0x16])]
    assert sent[8] == bytes([0, 0, 0x03])


def test_a_fault_the_chip_latches_reaches_the_poller_once_then_clears(hw: Hardware) -> None:
    x, y, _ = chips_of(hw)
    entry = next(e for e in hw.poller.entries if e.name.startswith("dSPIN chain"))
    assert all(st.fault is None for _, st in entry.poll())
    y.inject("OCD")
    y.inject("OCD", present=False)  # gone again before the poll: latched all the same
    readings = entry.poll()
    assert readings[0][1].fault is None
    fault = readings[1][1].fault
    assert fault is not None and "OCD" in fault and "L6480" in fault
    assert all(st.fault is None for _, st in entry.poll())  # GetStatus cleared it
    x.inject("UVLO")  # present: reported at every poll while it lasts
    assert "UVLO" in (entry.poll()[0][1].fault or "")
    assert "UVLO" in (entry.poll()[0][1].fault or "")
    driver = hw.steppers[0].driver
    assert isinstance(driver, DspinDriver) and driver.fault_counts
    assert driver.stats()["device"] == "/dev/spidev0.1"


def test_a_thermal_warning_is_logged_not_a_fault(
    hw: Hardware, caplog: pytest.LogCaptureFixture
) -> None:
    x, _, _ = chips_of(hw)
    entry = next(e for e in hw.poller.entries if e.name.startswith("dSPIN chain"))
    x.inject("TH_WRN")
    assert entry.poll()[0][1].fault is None
    assert "TH_WRN" in caplog.text


def test_a_chip_that_is_not_the_configured_one_stops_the_start() -> None:
    spec = spec_of(CHAIN)
    wrong = DspinChain([DspinChip(CHIPS[k]) for k in ("l6470", "l6470", "powerstep01")])
    hw = registry.backend("mock").build(spec, VirtualClock())
    try:
        with pytest.raises(
            DspinError, match=r"y: the L6480 at position 1 .* CONFIG 0x0000, not the L6480's 0x2C88"
        ):
            DspinLayer(factory=lambda: wrong).attach(hw, spec, hw.clock)
    finally:
        hw.close()
    assert wrong.opened is None  # closed again


def test_probe_names_each_chip_and_a_mismatch() -> None:
    spec = spec_of(CHAIN)
    chain = DspinChain([DspinChip(CHIPS[k]) for k in ("l6470", "l6470", "powerstep01")])
    report = ProbeReport()
    DspinLayer(factory=lambda: chain).probe(spec, VirtualClock(), report)
    text = report.text()
    assert "x: #0 on /dev/spidev0.1: configured L6470, CONFIG 0x2E88 (L6470)" in text
    assert "UVLO" in text  # STATUS read with GetParam: the power-up flag is still there
    assert [p.kind for p in report.problems] == [ProblemKind.MISMATCH]
    assert "y: the chip at position 1" in report.problems[0].text
    # nothing cleared (GetParam, not GetStatus), nothing written (STEP_MODE at its reset)
    assert all("UVLO" in c.latched and c.regs["STEP_MODE"] == 0x07 for c in chain.chips)


def test_probe_on_the_mock_finds_its_simulated_chain() -> None:
    report = registry.probe_hardware("mock", spec_of(CHAIN), VirtualClock())
    assert report.problems == []
    found = dict(report.sections)["dSPIN drivers"]
    assert [line.split(":")[0] for line in found] == ["x", "y", "z"]
    assert "configured L6480, CONFIG 0x2C88 (L6480)" in found[1]


def test_a_chip_that_stops_between_the_reads_of_one_ramp_status_is_not_yet_at_rest(
    hw: Hardware, monkeypatch: pytest.MonkeyPatch
) -> None:
    """STATUS is read first, then ABS_POS and SPEED: a chip that reaches its target (and
    a switch there) between those reads shows the target and SPEED 0 while its STATUS said
    it moves. Reported at rest, the executor would end the move there (DONE) without
    the switch's event, which only the next read shows: an end stop hit went unanswered
    (E4) in tests/motion/test_motor_e2e.py one run in three. It is reported moving, so the
    next read decides."""
    driver = hw.steppers[0].driver
    assert isinstance(driver, DspinDriver) and isinstance(hw.clock, VirtualClock)
    driver.watch(1)
    driver.move_to(4, 200.0, 2000.0, 2000.0)
    hw.clock.advance(0.001)
    real = driver.chain.exchange
    reads: list[int] = []

    def slow_bus(commands: dict[int, object]) -> dict[int, int]:
        got = real(commands)  # type: ignore[arg-type]
        reads.append(1)
        if len(reads) == 1:  # after the STATUS read: the chip ends its motion meanwhile
            hw.clock.advance(1.0)  # type: ignore[attr-defined]
        return got

    monkeypatch.setattr(driver.chain, "exchange", slow_bus)
    st = driver.ramp_status()
    assert len(reads) == 3 and st.position == 4
    assert st.velocity > 0  # not at rest: its STATUS said it moves
    monkeypatch.setattr(driver.chain, "exchange", real)
    assert driver.ramp_status().velocity == 0  # the next read: at rest at the target
