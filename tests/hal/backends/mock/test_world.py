"""The mock's simulated machine (world.py): a driver reports a stall only while its motor is
driven past an end stop, in the motor's logical direction, or while a stall is injected."""

from __future__ import annotations

from motorctl.hal.backends.mock.world import mock_axis
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.spec import HardwareSpec
from tests.support.mock_factory import MockFactory


def test_mock_stall_only_while_driven_past_the_stop(mock_factory: MockFactory) -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(mock_axis(endstop_min=-5, endstop_max=5),))
    hw = mock_factory.hardware(spec, clock)
    world = mock_factory.world(hw)
    out, driver = mock_factory.step_io(spec, clock, hw).outputs, hw.steppers[0].driver
    out.set_direction(0, True)
    for _ in range(5):
        out.pulse([0], 1e-6)
    assert not driver.status().stall and world.axes[0].position == 5
    out.pulse([0], 1e-6)
    assert driver.status().stall  # pushed past the max stop
    out.set_direction(0, False)
    assert not driver.status().stall  # backing out
    world.inject_stall(0, True)
    assert driver.status().stall
    world.inject_stall(0, False)
    for _ in range(12):
        out.pulse([0], 1e-6)
    assert world.axes[0].position == -6 and driver.status().stall
    spec2 = HardwareSpec(axes=(mock_axis(invert_dir=True, endstop_max=0),))
    hw2 = mock_factory.hardware(spec2, clock)
    out2 = mock_factory.step_io(spec2, clock, hw2).outputs
    out2.set_direction(0, True)
    out2.pulse([0], 1e-6)
    assert hw2.steppers[0].driver.status().stall  # logical direction, not the DIR level
