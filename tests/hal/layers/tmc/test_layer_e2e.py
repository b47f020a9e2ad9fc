"""motorctld as a real process with TMC drivers on (fake) SPI: start-up checks and E4 faults.

The daemon imports ``spidev`` as it would on a Raspberry Pi; tests/fakespi/spidev.py stands
in for py-spidev there, with register-level chip models (tests/support/tmc_model.py) behind it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.client.client import DeviceError
from motorctl.protocol.codec import ErrorCode
from tests.support.daemon_proc import DaemonProcess, StartDaemon, positions_until_ready
from tests.support.stand_ins import set_chips, stand_in_env, until_cleared, until_e4

CONFIG = """\
[drivers]
poll_ms = 5.0

[[motors]]
name = "x"
[motors.tmc]
driver = "tmc2130"
spi = "/dev/spidev0.0"

[[motors]]
name = "y"
[motors.tmc]
driver = "tmc5160"
spi = "/dev/spidev0.1"
run_current = 2.0
hold_current = 1.0

[[motors]]
name = "z"
  [motors.homing]
  max_travel = 20000
  [motors.tmc]
  driver = "tmc5160"
  spi = "/dev/spidev0.2"
  mode = "ramp"
  run_current = 2.0
  hold_current = 1.0
"""


@pytest.fixture
def fake_spi(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    control = tmp_path / "control.json"
    chips = {"0.0": "tmc2130", "0.1": "tmc5160:step_dir", "0.2": "tmc5160"}
    for name, value in stand_in_env("spidev", chips=chips, control=control).items():
        monkeypatch.setenv(name, value)
    return control


@pytest.fixture
def daemon(motorctld: StartDaemon, fake_spi: Path) -> DaemonProcess:
    return motorctld(CONFIG, kill_at_end=True)


def test_a_driver_fault_answers_e4_until_it_clears(daemon: DaemonProcess, fake_spi: Path) -> None:
    with daemon.client() as c:
        c.move_to(0, 50, speed=250)
        c.wait_moved(0, timeout_ms=10_000)
        set_chips(fake_spi, {"0.0": {"faults": [25]}})  # over-temperature on motor x
        until_e4(c, 0, 0, timeout_ms=10_000)
        with pytest.raises(DeviceError) as e:
            c.stop(0, hard=True)  # the driver still reports it: the fault stays
        assert e.value.code is ErrorCode.MOTOR_ERROR
        c.move_to(1, 100, speed=250)  # motor y is unaffected
        set_chips(fake_spi, {"0.0": {"faults": []}})
        until_cleared(c, 0)
        c.move_to(0, 10, speed=250)
        c.wait_moved(0, timeout_ms=10_000)
    drivers = daemon.status()["drivers"]
    assert [(d["chip"], d["device"]) for d in drivers] == [
        ("TMC2130", "/dev/spidev0.0"),
        ("TMC5160", "/dev/spidev0.1"),
        ("TMC5160", "/dev/spidev0.2"),
    ]
    assert drivers[0]["polls"] > 0 and drivers[0]["fault_counts"]["over-temperature (ot)"] == 1
    assert drivers[0]["spi_status_counts"]["reset_flag"] == 1  # the power-up reset, cleared
    assert daemon.terminate() == 0


def test_a_wrong_chip_stops_the_daemon_with_a_clear_message(tmp_path: Path, fake_spi: Path) -> None:
    wrong = CONFIG.replace('driver = "tmc2130"', 'driver = "tmc5160"', 1)
    with pytest.raises(RuntimeError) as e:
        DaemonProcess(tmp_path, wrong).start()
    msg = str(e.value)
    assert "/dev/spidev0.0" in msg and "found a TMC2130" in msg
    assert "Traceback" not in msg


def test_a_missing_spi_device_stops_the_daemon_naming_it(tmp_path: Path, fake_spi: Path) -> None:
    missing = CONFIG.replace("/dev/spidev0.1", "/dev/spidev1.0")
    with pytest.raises(RuntimeError) as e:
        DaemonProcess(tmp_path, missing).start()
    msg = str(e.value)
    assert "/dev/spidev1.0 does not exist" in msg and "Traceback" not in msg


def test_a_tmc5160_ramp_motor_moves_homes_and_reports_its_position(
    daemon: DaemonProcess, fake_spi: Path
) -> None:
    with daemon.client() as c:
        c.move_to(2, 800, speed=250)  # 1000 steps/s: XTARGET, VMAX, AMAX/DMAX on the chip
        seen = positions_until_ready(c, 2)  # 0.8 s, a look every 50 ms
        assert c.position(2) == 800
        assert any(0 < p < 800 for p in seen)  # GetAbsPos follows XACTUAL while moving
        set_chips(fake_spi, {"0.2": {"ref_l_at": 300}})  # REFL: 500 steps below here
        c.init_move(2, False, speed=1)  # home down onto the chip's left reference switch
        c.wait_moved(2, timeout_ms=20_000)
        # zero where the switch released again (XLATCH at its inactive edge), the chip
        # stopped a few steps on (a poll every ramp_poll_ms at second_speed)
        assert 0 <= c.position(2) <= 5
        c.move_to(2, 300, speed=250)
        c.wait_moved(2, timeout_ms=10_000)
        assert c.position(2) == 300
        c.move_to(2, 0, speed=250)  # back to zero: off the switch, no E4
        c.wait_moved(2, timeout_ms=10_000)
        assert c.position(2) == 0
    assert daemon.terminate() == 0


def test_with_a_ramp_motor_the_status_still_has_the_step_edges_histogram(
    daemon: DaemonProcess,
) -> None:
    """Motor z runs on its TMC5160's own ramp, so the daemon splits the motors between the
    step executor and the ramp executor: the lateness histogram is the step executor's
    (the ramp motor makes no STEP edges), and its process is still named."""
    with daemon.client() as c:
        c.move_to(0, 120, speed=250)  # STEP/DIR (TMC2130)
        c.move_to(2, 500, speed=250)  # the chip's ramp
        c.wait_moved(0, timeout_ms=10_000)
        c.wait_moved(2, timeout_ms=10_000)
        assert (c.position(0), c.position(2)) == (120, 500)
    status = daemon.status(histogram=True)
    steps = status["steps"]
    assert "histogram_us" not in daemon.status()["steps"]  # only when asked
    histogram = {int(us): n for us, n in steps["histogram_us"].items()}
    assert sum(histogram.values()) == steps["steps"] == 120  # motor 0's edges, not z's
    assert steps["p50_us"] <= steps["p99_us"] <= steps["p999_us"]
    assert status["executor"]["kind"] == "process" and status["executor"]["alive"]
    assert isinstance(status["executor"]["pid"], int)
    assert daemon.terminate() == 0
