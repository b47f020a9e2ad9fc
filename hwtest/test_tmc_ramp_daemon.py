"""The Raspberry Pi example with motor z's TMC5160 running its own ramp, wired with no STEP,
DIR or end-stop line (only its ENABLE), in the gpio-sim guest.

z's former lines (GPIO5, GPIO6, GPIO20) must stay free: nothing requests, drives or checks a
line the config does not name; its ENABLE is held on (low) by the daemon; z moves on its
chip model (tests/fakespi/, SD_MODE low) while x still steps on gpio-sim.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from hwtest import gsim
from hwtest.layout import GUEST_READY_TIMEOUT_S, MOTORS, where
from hwtest.test_tmc_daemon import API, REPO, example_config
from motorctl.hal.backends.gpiod.chip import load_api
from tests.support.daemon_proc import DaemonProcess

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


def test_a_ramp_motor_without_step_dir_leaves_those_lines_alone(
    tmp_path: Path,
) -> None:
    for m in MOTORS:
        chip, off = where(m[3])
        gsim.sim_pull(off, True, chip)
    shim = str(REPO / "tests" / "fakespi")
    env = {
        "PYTHONPATH": os.pathsep.join(p for p in (shim, os.environ.get("PYTHONPATH")) if p),
        "MOTORCTL_FAKE_SPI": json.dumps({"chips": CHIPS}),
    }
    base = gsim.chip_base("gpiochip0")
    gsim.trace_start()  # every level the daemon sets, from its start to its exit
    d = DaemonProcess(tmp_path, ramp_config(), env=env, ready_timeout=GUEST_READY_TIMEOUT_S).start()
    try:
        api = load_api(API)
        for offset in (5, 6, 20):  # z's STEP, DIR, end stop in the example: not named now
            info = api.line_info("/dev/gpiochip0", offset)
            assert not info.used, f"GPIO{offset} is held by {info.consumer!r}"
        enable = api.line_info("/dev/gpiochip0", 30)
        assert enable.used and enable.consumer == "motorctl" and enable.output
        assert gsim.sim_value(30) is False  # ENABLE on (active low) while the daemon runs
        with d.client(timeout=10.0) as c:
            c.move_to(2, 500, speed=250)  # the chip's own ramp
            c.move_to(0, 100, speed=250)  # STEP/DIR on gpio-sim
            c.wait_moved(2, timeout_ms=20_000)
            c.wait_moved(0, timeout_ms=20_000)
            assert (c.position(0), c.position(2)) == (100, 500)
        assert d.terminate() == 0
    finally:
        d.close()
        gsim.trace_stop()
    events = gsim.trace_read()
    assert gsim.trace_lost() == 0, "the trace lost events: size the buffer"
    for offset in (5, 6, 20):  # never driven nor turned around
        assert not [e for e in events if e.gpio == base + offset], f"GPIO{offset} was touched"
    levels = [e.value for e in gsim.changes(gsim.sets(events, base + 30))]
    assert levels[0] == 0 and levels[-1] == 1  # ENABLE on at start, off at exit
    x_steps = [e for e in gsim.sets(events, base + 17) if e.value == 1]  # x's STEP: GPIO17
    assert len(x_steps) == 100
