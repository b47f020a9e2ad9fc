"""The backend contract: what every hardware backend must do, seen from outside.

The same tests run on the mock (``make test``) and on the gpiod backend against a real
kernel GPIO chip (gpio-sim) with libgpiod v1 and v2 (``make test-hw``, hwtest/run).
"""

from __future__ import annotations

import time

import pytest

from motorctl.hal.interfaces import BridgeState, HalError, MonotonicClock
from motorctl.hal.registry import open_hardware
from motorctl.hal.spec import PinSpec
from tests.contract.harness import Harness

OUT, IN = PinSpec(0, output=True, initial=True), PinSpec(1, output=False)


def test_output_pin_starts_at_initial_and_follows_writes(harness: Harness) -> None:
    hw = harness.open(pins=[OUT, PinSpec(2, output=True, initial=False)])
    assert harness.pin_level(0) is True
    assert harness.pin_level(2) is False
    pin = hw.pins[0]
    for level in (False, True, False):
        pin.write(level)
        assert harness.pin_level(0) is level
        assert pin.read() is level


def test_input_pin_reads_the_outside_level(harness: Harness) -> None:
    hw = harness.open(pins=[IN])
    for level in (True, False, True):
        harness.drive_pin(1, level)
        assert hw.pins[1].read() is level


def test_write_to_an_input_is_refused(harness: Harness) -> None:
    hw = harness.open(pins=[IN])
    with pytest.raises(ValueError, match="input"):
        hw.pins[1].write(True)


def test_configure_switches_direction_both_ways(harness: Harness) -> None:
    hw = harness.open(pins=[OUT])
    pin = hw.pins[0]
    pin.configure(output=False)
    assert not pin.is_output
    for level in (False, True):
        harness.drive_pin(0, level)
        assert pin.read() is level
    pin.configure(output=True, level=False)
    assert pin.is_output
    assert harness.pin_level(0) is False
    pin.write(True)
    assert harness.pin_level(0) is True


def test_step_pulses_are_counted_outside_and_dir_follows(harness: Harness) -> None:
    harness.open(motors=2)
    out = harness.step_io().outputs
    out.set_direction(0, True)
    out.set_direction(1, False)
    assert harness.dir_level(0) is True
    assert harness.dir_level(1) is False
    harness.count_steps()
    for _ in range(25):
        out.pulse([0], 2e-6)
    for _ in range(7):
        out.pulse([1], 2e-6)
    for _ in range(3):
        out.pulse([0, 1], 2e-6)  # both motors' STEP lines in one call
    assert harness.steps(0) == 28
    assert harness.steps(1) == 10
    out.set_direction(0, False)
    assert harness.dir_level(0) is False


def test_inverted_dir_swaps_the_level(harness: Harness) -> None:
    harness.open(motors=1, invert_dir=True)
    harness.step_io().outputs.set_direction(0, True)
    assert harness.dir_level(0) is False


def test_pulse_before_direction_is_refused(harness: Harness) -> None:
    harness.open(motors=1)
    with pytest.raises(RuntimeError, match="direction"):
        harness.step_io().outputs.pulse([0], 2e-6)


@pytest.mark.parametrize("active_low", [False, True])
def test_endstops_are_edges_with_the_logical_level(harness: Harness, active_low: bool) -> None:
    harness.open(motors=1, endstop_active_low=active_low)
    io = harness.step_io()
    lo, hi = io.endstops[0]
    assert lo is not None and hi is not None
    for which, line in (("min", lo), ("max", hi)):
        for i, level in enumerate((False, True, False, True)):  # the first only sets a start
            harness.drive_endstop(0, which, level)
            active = level != active_low
            deadline = time.monotonic() + 2.0
            seen = []
            while io.inputs.level(line) is not active:  # edge events come through the kernel
                seen += io.inputs.read_edges()
                assert time.monotonic() < deadline, f"{which} end stop never read {active}"
                time.sleep(0.001)
            seen += io.inputs.read_edges()
            if harness.external and i > 0:  # a change: the kernel reported it as an edge
                assert any(e.line == line and e.active is active for e in seen), seen


def test_bridge_states_show_on_its_inputs(harness: Harness) -> None:
    hw = harness.open(dc=True)
    assert hw.dc is not None
    assert harness.bridge() is BridgeState.COAST
    for state in (
        BridgeState.FORWARD,
        BridgeState.BRAKE,
        BridgeState.REVERSE,
        BridgeState.COAST,
        BridgeState.FORWARD,
    ):
        hw.dc.set(state)
        assert harness.bridge() is state


def test_close_releases_everything(harness: Harness) -> None:
    spec_pins = [OUT, IN]
    harness.open(motors=2, pins=spec_pins, dc=True)
    harness.close()
    hw = harness.open(motors=2, pins=spec_pins, dc=True)  # would be busy if anything leaked
    assert len(hw.steppers) == 2


def test_unknown_backend_is_a_clear_error(harness: Harness) -> None:
    spec = harness.spec(1, [], False)
    with pytest.raises(HalError, match="unknown hardware backend 'nope'"):
        open_hardware("nope", spec, MonotonicClock())
