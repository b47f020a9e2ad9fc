"""The gpiod backend's declaration (config.py), checked without any GPIO hardware: [gpiod],
[motors.gpiod], [pins.gpiod], the wiring they give, the mistakes named before anything
opens (a motor whose TMC5160 runs its own ramp needs no STEP/DIR), the example config.
(The backend itself runs on gpio-sim in the hardware tier.)"""

from __future__ import annotations

import subprocess
import sys

import pytest

from motorctl.daemon.config import ConfigError, parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.backends.gpiod.config import (
    GpiodAxisConfig,
    GpiodConfig,
    GpiodPinConfig,
    make,
    wiring_of,
)
from motorctl.hal.backends.gpiod.wiring import LineRef
from tests.support import REPO

REPO = REPO
EXAMPLE = REPO / "docs" / "examples" / "raspberry-pi.toml"
SOURCE = "/etc/motorctl.toml"

BASE = """
[hal]
backend = "gpiod"
[[motors]]
[motors.gpiod]
step = "gpiochip0:17"
dir = "GPIO27"
[[pins]]
number = 3
gpiod = { line = "/dev/gpiochip1:4", bias = "pull-up" }
"""


def error_of(text: str) -> str:
    with pytest.raises(ConfigError) as err:
        parse_config(text, SOURCE)
    return str(err.value)


def test_wiring_from_the_sections() -> None:
    config = parse_config(BASE, SOURCE)
    w = wiring_of(hardware_spec(config))
    assert w.api == "auto" and w.consumer == "motorctl"
    assert w.motors[0].step == LineRef("gpiochip0", 17)
    assert w.motors[0].dir == LineRef(name="GPIO27")
    assert w.motors[0].enable is None and w.motors[0].endstop_min is None
    assert w.pins[0].number == 3 and w.pins[0].bias == "pull-up"
    assert w.dc is None
    assert [use for use, _ in w.lines()] == ["motors[0].step", "motors[0].dir", "pins.3"]


def test_section_defaults() -> None:
    top, axis = make(GpiodConfig), make(GpiodAxisConfig, step="GPIO1", dir="GPIO2")
    assert (top.api, top.consumer, top.dc) == ("auto", "motorctl", None)
    assert (axis.enable, axis.enable_active_low, axis.dir_hold_us) == ("", True, 0.0)
    assert (axis.endstop_min_bias, make(GpiodPinConfig, line="GPIO3").bias) == ("as-is", "as-is")
    dc = make(GpiodConfig, dc={"in1": "GPIO1", "in2": "GPIO2"}).dc
    assert dc is not None
    assert (dc.en, dc.dead_time_ms, dc.reverse_via, dc.pwm) == ("", 0.0, "coast", None)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            BASE.replace('dir = "GPIO27"', 'dir = "gpiochip0:17"'),
            "gpiod: line gpiochip0:17 is used twice: by motors[0].step and by motors[0].dir",
        ),
        (BASE.replace('dir = "GPIO27"', ""), "motors[0].gpiod.dir: missing"),
        (
            BASE.replace('step = "gpiochip0:17"', 'step = "17"'),
            'motors[0].gpiod.step = "17": not a GPIO line',
        ),
        (
            BASE.replace('gpiod = { line = "/dev/gpiochip1:4", bias = "pull-up" }', ""),
            "pins[0].gpiod: missing: the gpiod backend needs the pin's line",
        ),
        (BASE + "[dc]\n", "gpiod.dc: missing: [dc] configures a DC motor; wire its bridge"),
        (BASE.replace('bias = "pull-up"', 'bias = "up"'), 'pins[0].gpiod.bias = "up"'),
        (BASE + '[gpiod]\napi = "v3"\n', 'gpiod.api = "v3": unknown value'),
        (BASE + '[gpiod]\nconsumer = "my daemon"\n', "gpiod.consumer"),
    ],
)
def test_wiring_mistakes_are_named_before_anything_opens(text: str, expected: str) -> None:
    assert expected in error_of(text)


def test_other_backends_need_no_wiring_but_a_written_section_is_still_checked() -> None:
    assert parse_config("[[motors]]\n", SOURCE).hal.backend == "mock"
    mock = BASE.replace('backend = "gpiod"', 'backend = "mock"')
    assert parse_config(mock.replace('dir = "GPIO27"', 'dir = "gpiochip0:17"'), SOURCE)
    assert "not a GPIO line" in error_of(mock.replace('dir = "GPIO27"', 'dir = "27"'))


def test_the_example_config_passes_check_config() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.main", "--check-config", str(EXAMPLE)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "3 motors, 8 pins, a DC motor, backend gpiod" in out.stdout


# ------------------------------------------------ a TMC5160 that runs its own ramp: no STEP/DIR

RAMP_TMC = """
  [motors.tmc]
  driver = "tmc5160"
  spi = "/dev/spidev0.{cs}"
  mode = "{mode}"
"""


def with_motor(gpiod: str, mode: str = "ramp", name: str = "r") -> str:
    """BASE with a second motor driven by a TMC5160 over /dev/spidev0.1 in ``mode``."""
    return BASE + f'[[motors]]\nname = "{name}"\n' + gpiod + RAMP_TMC.format(cs=1, mode=mode)


def test_a_ramp_motor_needs_no_gpiod_section_and_gets_no_line() -> None:
    config = parse_config(with_motor(""), SOURCE)
    spec = hardware_spec(config)
    assert spec.stepped() == (0,)  # the ramp motor is not the step executor's
    w = wiring_of(spec)
    assert w.motors[1].own_ramp and w.motors[1].step is None and w.motors[1].dir is None
    assert [use for use, _ in w.lines()] == ["motors[0].step", "motors[0].dir", "pins.3"]


def test_a_ramp_motor_may_wire_only_its_enable_line() -> None:
    w = wiring_of(
        hardware_spec(
            parse_config(with_motor('  [motors.gpiod]\n  enable = "gpiochip0:9"\n'), SOURCE)
        )
    )
    assert [use for use, _ in w.lines()] == [
        "motors[0].step",
        "motors[0].dir",
        "motors[1].enable",
        "pins.3",
    ]


def test_step_dir_named_for_a_ramp_motor_are_still_checked_for_clashes() -> None:
    text = with_motor('  [motors.gpiod]\n  step = "gpiochip0:17"\n  dir = "gpiochip0:18"\n')
    assert "line gpiochip0:17 is used twice: by motors[0].step and by motors[1].step" in error_of(
        text
    )


@pytest.mark.parametrize(
    ("gpiod", "mode", "expected"),
    [
        (
            "",
            "step_dir",
            "motors[1].gpiod: missing: motor 1 ('r') is moved by STEP/DIR pulses; "
            "name its step and dir lines",
        ),
        (
            '  [motors.gpiod]\n  dir = "gpiochip0:6"\n',
            "step_dir",
            "motors[1].gpiod.step: missing: motor 1 ('r') is moved by STEP/DIR pulses and needs "
            "its STEP line",
        ),
        (
            '  [motors.gpiod]\n  step = "gpiochip0:5"\n',
            "step_dir",
            "motors[1].gpiod.dir: missing: motor 1 ('r') is moved by STEP/DIR pulses and needs "
            "its DIR line",
        ),
        (
            '  [motors.gpiod]\n  endstop_max = "gpiochip0:7"\n',
            "ramp",
            "motors[1].gpiod.endstop_max = \"gpiochip0:7\": motor 1 ('r')'s TMC5160 runs its own "
            "ramp and stops at its REFL/REFR inputs",
        ),
    ],
)
def test_only_a_ramp_motor_goes_without_step_dir(gpiod: str, mode: str, expected: str) -> None:
    msg = error_of(with_motor(gpiod, mode))
    assert expected in msg
    assert "only a TMC5160 that runs its own ramp" in msg or mode == "ramp"
    assert "the default value" not in msg  # missing, not defaulted


def test_a_motor_without_a_driver_chip_still_needs_step_and_dir() -> None:
    text = BASE + '[[motors]]\n[motors.gpiod]\nenable = "gpiochip0:9"\n'
    expected = "motors[1].gpiod.step: missing: motor 1 ('motor1') is moved by STEP/DIR"
    assert expected in error_of(text)
