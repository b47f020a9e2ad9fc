"""The Raspberry Pi example with motor z's TMC5160 running its own ramp, wired with no STEP,
DIR or end-stop line (only its ENABLE), in the gpio-sim guest.

z's former lines (GPIO5, GPIO6, GPIO20) must stay free: nothing requests, drives or checks a
line the config does not name; its ENABLE is held on (low) by the daemon; z moves on its
chip model (tests/fakespi/, SD_MODE low) while x still steps on gpio-sim.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator

import pytest

from hwtest import gsim
from hwtest.layout import MOTORS, where
from hwtest.test_tmc_daemon import API, REPO, example_config
from motorctl.hal.gpiochip import load_api
from tests.daemon_proc import DaemonProcess

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")

Z_STEP_DIR = """\
  [motors.gpiod]
  step = "GPIO5"
  dir = "GPIO6"
  endstop_min = "GPIO20"
  endstop_min_bias = "pull-up"
  [motors.tmc]                 # the driver chip on SPI (docs/tmc.md); STEP/DIR move it
  driver = "tmc5160"
  spi = "/dev/spidev0.2"
"""
Z_RAMP = """\
  [motors.gpiod]
  enable = "gpiochip0:30"
  [motors.tmc]
  driver = "tmc5160"
  spi = "/dev/spidev0.2"
  mode = "ramp"
"""
CHIPS = {"0.0": "tmc5160:step_dir", "0.1": "tmc5160:step_dir", "0.2": "tmc5160"}


def ramp_config() -> str:
    text = example_config()
    assert text.count(Z_STEP_DIR) == 1
    return text.replace(Z_STEP_DIR, Z_RAMP)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    for m in MOTORS:
        chip, off = where(m[3])
        gsim.sim_pull(off, True, chip)
    tmp = tmp_path_factory.mktemp("ramp")
    shim = str(REPO / "tests" / "fakespi")
    env = {"PYTHONPATH": os.pathsep.join(p for p in (shim, os.environ.get("PYTHONPATH")) if p),
           "MOTORCTL_FAKE_SPI": json.dumps({"chips": CHIPS})}
    d = DaemonProcess(tmp, ramp_config(), env=env).start()
    try:
        yield d
    finally:
        d.close()


def test_a_ramp_motor_without_step_dir_leaves_those_lines_alone(daemon: DaemonProcess) -> None:
    api = load_api(API)
    for offset in (5, 6, 20):  # z's STEP, DIR, end stop in the example: not named now
        info = api.line_info("/dev/gpiochip0", offset)
        assert not info.used, f"GPIO{offset} is held by {info.consumer!r}"
    enable = api.line_info("/dev/gpiochip0", 30)
    assert enable.used and enable.consumer == "motorctl" and enable.output
    assert gsim.sim_value(30) is False  # ENABLE on (active low) while the daemon runs
    with daemon.client(timeout=10.0) as c:
        c.move_to(2, 500, speed=250)  # the chip's own ramp
        c.move_to(0, 100, speed=250)  # STEP/DIR on gpio-sim
        c.wait_moved(2, timeout_ms=20_000)
        c.wait_moved(0, timeout_ms=20_000)
        assert (c.position(0), c.position(2)) == (100, 500)
    assert daemon.terminate() == 0
