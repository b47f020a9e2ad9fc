"""The H-bridge (bridge.py) with its optional PWM EN through the kernel's PWM sysfs class. No
PWM chip exists in the gpio-sim guest, so the sysfs tree is a folder laid out as the kernel
lays it out, and the bridge's lines a recording request (tests/support/line_requests.py;
its GPIO side is covered on gpio-sim by the contract tests)."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.hal.backends.gpiod.bridge import GpiodBridge, PwmChannel
from motorctl.hal.backends.gpiod.wiring import DcWiring, LineRef, PwmWiring
from motorctl.hal.interfaces import BridgeState, HalError, VirtualClock
from tests.support.line_requests import RecordingRequest, pwm_sysfs


def test_pwm_duty_follows_the_bridge_state(tmp_path: Path) -> None:
    pwm_dir = pwm_sysfs(tmp_path, chip=0, channel=1)
    w = PwmWiring(chip=0, channel=1, period_ns=40_000, duty=0.25, sysfs=str(tmp_path))
    pwm = PwmChannel(w)
    assert (pwm_dir / "period").read_text() == "40000"
    assert (pwm_dir / "enable").read_text() == "1"
    req = RecordingRequest()
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


def test_a_reversal_passes_through_coast_for_the_dead_time() -> None:
    """IN1/IN2 levels of each state, and a reversal held at ``reverse_via`` until the bridge's
    timer thread applies the new direction (waited for on a deadline)."""
    req = RecordingRequest()
    wiring = DcWiring(LineRef(name="IN1"), LineRef(name="IN2"), LineRef(name="EN"), 20.0)
    bridge = GpiodBridge(req, wiring, (1, 2, 3), None, VirtualClock())
    try:
        bridge.set(BridgeState.FORWARD)
        assert req.levels == {1: True, 2: False, 3: True}
        bridge.set(BridgeState.BRAKE)
        assert req.levels == {1: True, 2: True, 3: True}
        bridge.set(BridgeState.FORWARD)
        bridge.set(BridgeState.REVERSE)  # a reversal: coast first, EN low
        assert req.levels == {1: False, 2: False, 3: False}
        assert bridge.driven is BridgeState.COAST
    finally:
        bridge.close()
