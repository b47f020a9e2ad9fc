"""The dSPIN chips' FLAG and BUSY outputs as edge inputs (``[motors.dspin] flag``/``busy``,
``Hardware.open_alert_lines``): on the mock the chip models drive the lines; a daemon on a
virtual clock judges what the host sees. FLAG falling makes the driver poller read the
chain at once, so a fault reaches the host's next command long before the poll period;
BUSY high at rest answers the executor's reads without SPI; the config refuses a line used
twice. No timed assert: the clock is virtual."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal import registry
from motorctl.hal.backends.mock.dspin_chain import DspinChain
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import MonotonicClock
from motorctl.hal.layers.dspin.driver import DspinDriver
from motorctl.hal.poller import Polled, Reading
from motorctl.protocol.codec import ErrorCode, GetAbsPos, IsReady, MoveTo
from motorctl.schema import ConfigError
from tests.support.sessions import SessionRig

#: two chips on one chain; FLAG wired-OR on one line, each chip's BUSY on a line of its own
CHAIN = """\
[[motors]]
name = "x"
  [motors.dspin]
  driver = "l6470"
  spi = "/dev/spidev0.0"
  microsteps = 8
  flag = "GPIO25"
  busy = "GPIO24"
[[motors]]
name = "y"
  [motors.dspin]
  driver = "l6480"
  spi = "/dev/spidev0.0"
  position = 1
  flag = "GPIO25"
  busy = "GPIO23"
"""
#: the same machine without the lines
UNWIRED = "\n".join(ln for ln in CHAIN.splitlines() if not ln.strip().startswith(("flag", "busy")))


def rig_of(tmp: Path, text: str) -> SessionRig:
    rig = SessionRig(tmp, text)
    rig.run(0.2)
    return rig


def chain_of(rig: SessionRig) -> tuple[DspinChain, list[DspinChip], Polled]:
    nodes = world_of(rig.daemon.hw).spi_nodes
    assert nodes is not None
    chain = nodes.chains[(0, 0)]
    entry = next(e for e in rig.daemon.hw.poller.entries if e.name.startswith("dSPIN"))
    return chain.chain, [m.chip for m in chain.members], entry


def just_after_a_poll(rig: SessionRig, entry: Polled) -> None:
    """Run until the chain's poll has just been made (the longest wait for the next)."""
    rig.run(entry.due - rig.now + 0.0002)
    assert entry.due - rig.now > 0.019  # [drivers] poll_ms = 20: the next one is far


@pytest.mark.parametrize("wired", [True, False])
def test_a_fault_reaches_the_hosts_next_command_at_once_with_flag_else_at_the_poll(
    tmp_path: Path, wired: bool
) -> None:
    rig = rig_of(tmp_path, CHAIN if wired else UNWIRED)
    _, (_, y), entry = chain_of(rig)
    assert rig.call(IsReady(1)).error_code is None
    just_after_a_poll(rig, entry)
    polls = entry.polls
    y.inject("OCD")
    rig.run(0.001)  # a millisecond later, well inside the poll period of 20 ms
    answer = rig.call(IsReady(1)).error_code
    # the status's count of them: each chip on the FLAG line (wired-OR: both), null unwired
    said = [
        (d.stats() or {}).get("flag_alerts") for d in (s.driver for s in rig.daemon.hw.steppers)
    ]
    if wired:  # FLAG fell: the chain was read at once, the motor faulted
        assert answer is ErrorCode.MOTOR_ERROR
        assert entry.polls == polls + 1 and entry.alerts == 1
        assert said == [1, 1]
    else:  # the poll has not come yet: the host still hears a healthy motor
        assert answer is None and entry.polls == polls and entry.alerts == 0
        assert said == [None, None]
        rig.run(0.020)  # the next poll reads it
        assert rig.call(IsReady(1)).error_code is ErrorCode.MOTOR_ERROR
    assert rig.call(IsReady(0)).error_code is None  # the other chip of the wired-OR: fine


def idle_transfers(rig: SessionRig, chain: DspinChain, seconds: float) -> int:
    start = chain.count
    rig.run(seconds)
    return chain.count - start


@pytest.mark.parametrize("wired", [True, False])
def test_busy_tells_a_motor_at_rest_without_spi_and_the_idle_cost_stays_in_budget(
    tmp_path: Path, wired: bool
) -> None:
    rig = rig_of(tmp_path, CHAIN if wired else UNWIRED)
    chain, (x, _), _ = chain_of(rig)
    driver = rig.daemon.hw.steppers[0].driver
    assert isinstance(driver, DspinDriver)
    assert rig.call(MoveTo(0, True, 1000, 100, 50, 50)).error_code is None
    rig.run(0.05)
    assert x.busy and not rig.call(IsReady(0)).as_bool  # the chip runs its GoTo
    busy = driver.busy_line
    if wired:
        assert busy is not None and busy.read_edges() and busy.level(0)  # the line is low
    for _ in range(200):
        if rig.call(IsReady(0)).as_bool:
            break
        rig.run(0.05)
    assert rig.call(IsReady(0)).as_bool and not x.busy
    assert rig.call(GetAbsPos(0)).as_position == 1000
    if wired:
        assert busy is not None and busy.read_edges() == [] and not busy.level(0)
    answered = driver.busy_answers
    n = idle_transfers(rig, chain, 2.0)  # 2 s of the virtual clock at rest
    # the driver poller's GetStatus (3 transfers every 20 ms): 150 per second; the
    # executor's reads (GetParam STATUS and ABS_POS, 7 transfers per chip every 50 ms at
    # rest: 280 per second for the two) only without BUSY
    assert n / 2.0 <= 1000  # issue 34: the poller's cost, at most 1000 per chain per second
    if wired:
        assert driver.busy_answers > answered
        assert n / 2.0 < 300
    else:
        assert driver.busy_answers == answered == 0
        assert n / 2.0 > 400


#: the second chip alone on a chain of its own (its FLAG line still the first's)
TWO_CHAINS = CHAIN.replace('spi = "/dev/spidev0.0"\n  position = 1', 'spi = "/dev/spidev0.1"')


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (
            CHAIN.replace('busy = "GPIO23"', 'busy = "GPIO25"'),
            'motors[1].dspin.busy = "GPIO25": also the FLAG line of motors[0]: a line used twice',
        ),
        (
            TWO_CHAINS,
            'motors[1].dspin.flag = "GPIO25": also the FLAG line of motors[0] on another '
            "chain (/dev/spidev0.0): a line used twice",
        ),
        (CHAIN.replace('flag = "GPIO25"', 'flag = "GPIO 25"', 1), "motors[0].dspin.flag"),
    ],
)
def test_a_line_used_twice_or_not_a_line_is_refused_naming_both(text: str, says: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "t.toml")
    assert says in str(info.value)


def test_every_chip_of_a_chain_may_share_its_flag_and_busy_line() -> None:
    text = CHAIN.replace('busy = "GPIO23"', 'busy = "GPIO24"')
    parse_config(text, "t.toml")  # wired-OR within one chain: accepted


def test_the_poller_thread_wakes_on_flag_not_on_its_period() -> None:
    """A real clock: the ``motorctl-drivers`` thread waits on the FLAG line's descriptor.
    Its period is 10000 s here, so a read within the 5 s deadline can only be FLAG's."""
    spec = hardware_spec(parse_config(CHAIN + "[drivers]\npoll_ms = 10000\n", "t.toml"))
    hw = registry.open_hardware("mock", spec, MonotonicClock())
    read = threading.Event()
    faults: list[str] = []

    def sink(readings: Sequence[Reading]) -> None:
        faults.extend(st.fault or "" for _, st in readings)
        read.set()

    try:
        hw.poller.connect(sink)
        hw.poller.start()  # the first pass reads every chip on this thread
        nodes = world_of(hw).spi_nodes
        assert nodes is not None
        entry = next(e for e in hw.poller.entries if e.name.startswith("dSPIN"))
        polls = entry.polls
        nodes.chains[(0, 0)].members[0].chip.inject("UVLO")
        assert read.wait(5.0), "FLAG fell and the poller did not read the chain"
        assert entry.polls == polls + 1 and entry.alerts == 1
        assert "UVLO" in faults[0]
    finally:
        hw.close()
    assert not hw.poller.running
