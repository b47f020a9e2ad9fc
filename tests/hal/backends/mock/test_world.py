"""The mock's simulated machine (world.py): each end stop is a switch, active at its position
and beyond (none with ``switches = false``), and a hard stop there: a pulse that would take
the axis further is lost, and the driver reports a stall while its motor keeps pushing that
way (in the motor's logical direction), or while a stall is injected."""

from __future__ import annotations

from motorctl.hal.backends.mock.world import mock_axis
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.spec import HardwareSpec
from tests.support.mock_factory import MockFactory


def test_mock_stall_only_while_pushed_against_the_stop(mock_factory: MockFactory) -> None:
    clock = VirtualClock()
    spec = HardwareSpec(axes=(mock_axis(endstop_min=-5, endstop_max=5),))
    hw = mock_factory.hardware(spec, clock)
    world = mock_factory.world(hw)
    out, driver = mock_factory.step_io(spec, clock, hw).outputs, hw.steppers[0].driver
    out.set_direction(0, True)
    for _ in range(5):
        out.pulse([0], 1e-6)
    assert not driver.status().stall and world.axes[0].position == 5  # at the stop: no push
    out.pulse([0], 1e-6)
    assert driver.status().stall  # pushed against the max stop: the pulse is lost
    assert world.axes[0].position == 5
    out.set_direction(0, False)
    assert not driver.status().stall  # backing out
    out.pulse([0], 1e-6)
    out.set_direction(0, True)
    out.pulse([0], 1e-6)
    assert world.axes[0].position == 5 and not driver.status().stall  # back, not pushing
    world.inject_stall(0, True)
    assert driver.status().stall
    world.inject_stall(0, False)
    out.set_direction(0, False)
    for _ in range(12):
        out.pulse([0], 1e-6)
    assert world.axes[0].position == -5 and driver.status().stall
    spec2 = HardwareSpec(axes=(mock_axis(invert_dir=True, endstop_max=0),))
    hw2 = mock_factory.hardware(spec2, clock)
    out2 = mock_factory.step_io(spec2, clock, hw2).outputs
    out2.set_direction(0, True)
    out2.pulse([0], 1e-6)
    assert hw2.steppers[0].driver.status().stall  # logical direction, not the DIR level


def test_the_switch_is_active_from_its_position_on_and_only_with_switches(
    mock_factory: MockFactory,
) -> None:
    clock = VirtualClock()
    axes = (mock_axis(endstop_min=-2, endstop_max=2), mock_axis(-2, 2, switches=False))
    spec = HardwareSpec(axes=axes)
    hw = mock_factory.hardware(spec, clock)
    io = mock_factory.step_io(spec, clock, hw)
    out, inputs = io.outputs, io.inputs
    levels: list[tuple[int, bool, bool]] = []
    out.set_direction(0, False)
    out.set_direction(1, False)
    for _ in range(4):
        out.pulse([0, 1], 1e-6)
        pos = mock_factory.world(hw).axes[0].position
        levels.append((pos, inputs.level(0), inputs.level(2)))
    # active at -2 exactly, released at -1: no hysteresis; never without switches
    assert levels == [(-1, False, False), (-2, True, False), (-2, True, False), (-2, True, False)]
    assert [(e.line, e.active) for e in inputs.read_edges()] == [(0, True)]
    assert hw.steppers[1].driver.status().stall  # the hard stop is there all the same
