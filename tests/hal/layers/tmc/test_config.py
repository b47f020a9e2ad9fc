"""The TMC layer's declaration (config.py): [motors.tmc] becomes a motor's driver spec, and
what cannot work is refused when the config is read."""

from __future__ import annotations

import pytest

from motorctl.daemon.config import ConfigError, parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.layers.tmc.config import TmcDeclaration
from motorctl.hal.layers.tmc.tmc5160 import TMC5160

TMC_MOTOR = '[[motors]]\nname = "x"\n[motors.tmc]\n'


def config_error(text: str) -> str:
    with pytest.raises(ConfigError) as e:
        parse_config(text, "t.toml")
    return str(e.value)


def test_config_section_maps_to_the_driver_spec() -> None:
    config = parse_config(
        TMC_MOTOR + 'driver = "tmc5160"\nspi = "/dev/spidev1.2"\nmode = "ramp"\n'
        "run_current = 1.5\nhold_current = 0.5\nmicrosteps = 32\nstall_threshold = -4\n"
        "ref_left_active_low = true\n" + '[[motors]]\nname = "y"\n',
        "t.toml",
    )
    spec = TmcDeclaration().driver_spec(config.motors[0])
    assert spec is not None and TmcDeclaration().driver_spec(config.motors[1]) is None
    assert spec.spi == "/dev/spidev1.2" and spec.ramp and spec.ref_left_active_low
    s = spec.settings
    assert (s.chip, s.run_current, s.hold_current, s.microsteps, s.stall_threshold) == (
        TMC5160,
        1.5,
        0.5,
        32,
        -4,
    )
    axes = hardware_spec(config).axes
    assert axes[0].driver == spec and axes[0].name == "x" and axes[1].driver is None


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ('mode = "ramp"\n', 'motors[0].tmc.mode = "ramp": the ramp generator is a TMC5160'),
        ("microsteps = 12\n", "motors[0].tmc.microsteps = 12: not a power of two"),
        ("run_current = 5.0\n", "above the 1.74 A a TMC2130 gives with a 0.11 ohm"),
        ('spi = "/dev/spi0"\n', "/dev/spidevB.C"),
        ("hold_current = 2.0\n", "hold_current"),
        (
            'driver = "tmc5160"\nmode = "ramp"\n[motors.homing]\nsource = "stall"\n',
            "stall_min_speed > 0",
        ),
    ],
)
def test_config_section_refuses_what_cannot_work(body: str, expected: str) -> None:
    assert expected in config_error(TMC_MOTOR + body)


def test_config_refuses_one_spi_device_for_two_motors() -> None:
    text = TMC_MOTOR + '[[motors]]\nname = "y"\n[motors.tmc]\nspi = "/dev/spidev0.0"\n'
    assert "motors[1].tmc.spi" in config_error(text)
    assert "also the device of motors[0]" in config_error(text)
