"""The whole Raspberry Pi example, [motors.tmc] included, inside the gpio-sim guest.

GPIO is the kernel's (gpio-sim, both libgpiod APIs as the tier runs them); the three TMC5160s
on /dev/spidev0.0-0.2 are the register-level models of tests/support/tmc_model.py behind
the stand-in py-spidev of tests/fakespi/ (no chip can answer on the guest's SPI bus; the
bytes on a real kernel SPI bus are checked by hwtest/spi_wire.py). So the daemon starts the
example exactly as on a Pi: every driver identified, configured and read back, then watched.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwtest import gsim
from hwtest.layout import GUEST_READY_TIMEOUT_S, MOTORS, in_the_guest, where
from tests.support.daemon_proc import DaemonProcess, run_probe
from tests.support.stand_ins import set_chips, stand_in_env, until_cleared, until_e4

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")

REPO = Path(__file__).resolve().parent.parent
EXAMPLE = REPO / "docs" / "examples" / "raspberry-pi.toml"
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")
CHIPS = {"0.0": "tmc5160:step_dir", "0.1": "tmc5160:step_dir", "0.2": "tmc5160:step_dir"}


def example_config() -> str:
    """The documented example as the guest runs it (:func:`hwtest.layout.in_the_guest`)."""
    text = EXAMPLE.read_text()
    assert len(re.findall(r"^\s*\[motors\.tmc\]", text, re.M)) == 3
    return in_the_guest(text, API)


def shim_env(control: Path) -> dict[str, str]:
    """What makes the daemon's ``import spidev`` find the stand-in with the three models."""
    return stand_in_env("spidev", chips=CHIPS, control=control)


def test_probe_lists_the_three_drivers(tmp_path: Path) -> None:
    """Runs first, before the daemon below holds the lines."""
    config = tmp_path / "pi.toml"
    config.write_text(example_config())
    out = run_probe(config, env=shim_env(tmp_path / "control.json"))
    assert out.returncode == 0, out.stdout + out.stderr
    for i, name in enumerate(("x", "y", "z")):
        assert f"{name}: /dev/spidev0.{i}: TMC5160 (IOIN=0x30000040) ok" in out.stdout
    assert "DRV_STATUS=" in out.stdout and "SD_MODE=1 (external STEP/DIR)" in out.stdout


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[DaemonProcess, Path]]:
    for m in MOTORS:  # end stops clear (active low: pulled high)
        chip, off = where(m[3])
        gsim.sim_pull(off, True, chip)
    tmp = tmp_path_factory.mktemp("tmc")
    control = tmp / "control.json"
    d = DaemonProcess(
        tmp, example_config(), env=shim_env(control), ready_timeout=GUEST_READY_TIMEOUT_S
    ).start()
    try:
        yield d, control
    finally:
        d.close()


def test_the_example_starts_with_its_three_tmc5160s(daemon: tuple[DaemonProcess, Path]) -> None:
    d, _ = daemon
    assert "gpiod hardware" in d.ready_line
    drivers = d.status()["drivers"]
    assert [(x["chip"], x["device"]) for x in drivers] == [
        ("TMC5160", f"/dev/spidev0.{i}") for i in range(3)
    ]
    assert all(x["polls"] > 0 and x["spi_errors"] == 0 for x in drivers)


def test_a_driver_fault_on_spi_answers_e4_while_gpio_steps_the_others(
    daemon: tuple[DaemonProcess, Path],
) -> None:
    d, control = daemon
    with d.client(timeout=10.0) as c:
        c.move_to(1, 200, speed=250)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.position(1) == 200
        set_chips(control, {"0.0": {"faults": [25]}})  # x: over-temperature
        until_e4(c, 0, 100, timeout_ms=20_000)
        set_chips(control, {"0.0": {"faults": []}})
        until_cleared(c, 0)
        c.move_to(1, 0, speed=250)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.position(1) == 0
