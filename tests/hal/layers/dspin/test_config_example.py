"""docs/examples/dspin.toml: the embedded world's motors, pins and DC motor with each motor
on a mock dSPIN chip of one chain (an L6470, an L6480, a powerSTEP01); the daemon started
on it serves moves, homing and pins over a PTY."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from motorctl.daemon.config import load_config
from motorctl.hal.backends.mock.config import MockConfig
from motorctl.hal.layers.dspin.config import DspinAxisConfig
from tests.support.daemon_proc import StartDaemon

EXAMPLE = Path(__file__).resolve().parents[4] / "docs" / "examples" / "dspin.toml"


def test_the_example_is_the_embedded_world_on_one_dspin_chain() -> None:
    example, world = load_config(EXAMPLE), load_config(None)
    chips = [m.section(DspinAxisConfig) for m in example.motors]
    assert [(c.driver, c.spi, c.position) for c in chips] == [
        ("l6470", "/dev/spidev0.0", 0),
        ("l6480", "/dev/spidev0.0", 1),
        ("powerstep01", "/dev/spidev0.0", 2),
    ]
    without = {DspinAxisConfig: None}
    motors = tuple(replace(m, sections={**m.sections, **without}) for m in example.motors)
    assert motors == world.motors  # the same motors but for their chips
    assert example.pins == world.pins and example.dc == world.dc
    assert example.section(MockConfig) == world.section(MockConfig)


def test_the_daemon_serves_the_example(motorctld: StartDaemon) -> None:
    daemon = motorctld(EXAMPLE.read_text())
    with daemon.client() as c:
        for motor in range(3):
            c.move_to(motor, 400 * (motor + 1), speed=250)
        for motor in range(3):
            c.wait_moved(motor, timeout_ms=20_000)
            assert c.position(motor) == 400 * (motor + 1)
            c.init_move(motor, False, speed=4)
        for motor in range(3):
            c.wait_moved(motor, timeout_ms=30_000)
            assert c.position(motor) == 0
        c.move_to(1, 700, speed=250)  # home and waypoints: GoTo_DIR to saved positions
        c.wait_moved(1, timeout_ms=20_000)
        c.save_home(1)
        c.move_to(1, 300, speed=250)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.save_waypoint(1) == 0
        c.go_home(1)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.position(1) == 700
        c.move_to_waypoint(1, 0, speed=250)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.position(1) == 300
        c.set_pin(0, True)  # wired to pin 4 in the embedded world
        assert c.get_pin(4)
    assert [d["chip"] for d in daemon.status()["drivers"]] == [
        "L6470",
        "L6480",
        "powerSTEP01 (voltage mode)",
    ]
