"""The mock backend as gpiozero's ``MockFactory``: simulated machines built the way the daemon
builds them (through the registry, with the layers the spec uses), each closed when the test
ends. The ``mock_factory`` fixture (tests/conftest.py) hands one to a test."""

from __future__ import annotations

from motorctl.hal.backends.mock.world import MockWorld, world_of
from motorctl.hal.interfaces import Clock, Hardware, StepIO, VirtualClock
from motorctl.hal.registry import open_hardware, open_step_io
from motorctl.hal.spec import HardwareSpec


class MockFactory:
    """Builds mock hardware and step IO; :meth:`close` closes all of it, newest first."""

    def __init__(self) -> None:
        self._open: list[Hardware | StepIO] = []

    def hardware(self, spec: HardwareSpec, clock: Clock | None = None) -> Hardware:
        """The daemon's part of a simulated machine (``open_hardware("mock", ...)``), on
        ``clock`` (default: a virtual clock)."""
        hw = open_hardware("mock", spec, clock or VirtualClock())
        self._open.append(hw)
        return hw

    def step_io(
        self, spec: HardwareSpec, clock: Clock | None = None, parent: Hardware | None = None
    ) -> StepIO:
        """A step executor's part (``open_step_io("mock", ...)``): on ``parent``'s world,
        or a world of its own without one."""
        io = open_step_io("mock", spec, clock or VirtualClock(), parent)
        self._open.append(io)
        return io

    @staticmethod
    def world(hw: Hardware) -> MockWorld:
        """The simulated world behind mock hardware (to poke: faults, end stops, pins)."""
        return world_of(hw)

    def close(self) -> None:
        while self._open:
            self._open.pop().close()
