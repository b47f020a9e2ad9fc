"""The H-bridge's optional PWM EN through the kernel's PWM sysfs class. No PWM chip exists in
the gpio-sim guest, so the sysfs tree is a directory laid out as the kernel lays it out
(pwmchipN/export creates pwmM/ with period, duty_cycle, enable); the bridge's lines are a
recording LineRequest (its GPIO side is covered on gpio-sim by the contract tests)."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.hal.backends.gpiod.backend import GpiodBridge, PwmChannel
from motorctl.hal.backends.gpiod.chip import Edge, LineRequest
from motorctl.hal.backends.gpiod.wiring import DcWiring, LineRef, PwmWiring
from motorctl.hal.interfaces import BridgeState, HalError, VirtualClock


class Recorder(LineRequest):
    def __init__(self) -> None:
        super().__init__("/dev/gpiochip0", {})
        self.levels: dict[int, bool] = {}

    def set_values(self, values: dict[int, bool]) -> None:
        self.levels.update(values)

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [self.levels.get(o, False) for o in offsets]

    def reconfigure(self, offset: int, settings: object) -> None:
        raise AssertionError("not used")

    def fileno(self) -> int:
        return -1

    def read_events(self) -> list[Edge]:
        return []

    def release(self) -> None:
        pass


def sysfs(tmp_path: Path) -> Path:
    chip = tmp_path / "pwmchip0"
    chip.mkdir()
    (chip / "export").write_text("")
    pwm = chip / "pwm1"  # what the kernel creates on export
    pwm.mkdir()
    for name in ("period", "duty_cycle", "enable"):
        (pwm / name).write_text("0")
    return pwm


def test_pwm_duty_follows_the_bridge_state(tmp_path: Path) -> None:
    pwm_dir = sysfs(tmp_path)
    w = PwmWiring(chip=0, channel=1, period_ns=40_000, duty=0.25, sysfs=str(tmp_path))
    pwm = PwmChannel(w)
    assert (pwm_dir / "period").read_text() == "40000"
    assert (pwm_dir / "enable").read_text() == "1"
    req = Recorder()
    wiring = DcWiring(LineRef(name="IN1"), LineRef(name="IN2"), None, pwm=w)
    bridge = GpiodBridge(req, wiring, (1, 2, None), pwm, VirtualClock())
    for state, duty in (
        (BridgeState.FORWARD, "10000"),
        (BridgeState.BRAKE, "40000"),
        (BridgeState.REVERSE, "10000"),
        (BridgeState.COAST, "0"),
    ):
        bridge.set(state)
        assert (pwm_dir / "duty_cycle").read_text() == duty, state
    assert req.levels == {1: False, 2: False}
    bridge.close()
    assert (pwm_dir / "enable").read_text() == "0"


def test_a_missing_pwm_chip_names_the_overlay_and_the_group(tmp_path: Path) -> None:
    w = PwmWiring(chip=3, channel=0, sysfs=str(tmp_path))
    with pytest.raises(HalError, match=r"pwmchip3.*dtoverlay=pwm.*group gpio"):
        PwmChannel(w)
