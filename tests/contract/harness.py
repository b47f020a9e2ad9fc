"""The backend contract's two sides: build hardware through a backend, and look at it from
outside (drive an input, see an output's level, count steps).

The contract tests (test_contract.py) run against :class:`MockHarness` in ``make test`` and
against the gpiod harness (hwtest/gpiod_harness.py) on gpio-sim in the VM tier
(``make test-hw``), with both libgpiod APIs. Test-owned state; single thread.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

from motorctl.hal.backends.mock.world import EventKind, MockWorld, world_of
from motorctl.hal.interfaces import BridgeState, Hardware, MonotonicClock, StepIO
from motorctl.hal.registry import open_hardware, open_step_io
from motorctl.hal.spec import AxisSpec, HardwareSpec, PinSpec


class Harness(ABC):
    """One backend under test and the world around it."""

    name: str
    backend: str
    #: whether step counts and levels are observed outside the backend's own objects
    external: bool = True

    def __init__(self) -> None:
        self.hw: Hardware | None = None
        self.io: StepIO | None = None

    def spec(
        self,
        motors: int,
        pins: Sequence[PinSpec],
        dc: bool,
        endstop_active_low: bool = False,
        invert_dir: bool = False,
    ) -> HardwareSpec:
        axes = tuple(
            AxisSpec(invert_dir=invert_dir, endstop_active_low=endstop_active_low)
            for _ in range(motors)
        )
        return HardwareSpec(axes, tuple(pins), dc=dc)

    def open(
        self,
        motors: int = 1,
        pins: Sequence[PinSpec] = (),
        dc: bool = False,
        endstop_active_low: bool = False,
        invert_dir: bool = False,
    ) -> Hardware:
        spec = self.spec(motors, pins, dc, endstop_active_low, invert_dir)
        clock = MonotonicClock()
        self.hw = open_hardware(self.backend, spec, clock)
        self.io = open_step_io(self.backend, spec, clock, parent=self.hw)
        self.opened(spec)
        return self.hw

    def opened(self, spec: HardwareSpec) -> None:  # noqa: B027 (an optional hook)
        """Hook: the hardware is open."""

    def step_io(self) -> StepIO:
        """The step executor's part: STEP/DIR outputs and end-stop edge inputs."""
        assert self.io is not None
        return self.io

    def close(self) -> None:
        if self.io is not None:
            self.io.close()
            self.io = None
        if self.hw is not None:
            self.hw.close()
            self.hw = None

    @abstractmethod
    def drive_pin(self, number: int, level: bool) -> None:
        """The outside world drives ``level`` onto pin ``number`` (an input)."""

    @abstractmethod
    def pin_level(self, number: int) -> bool:
        """The level an output pin drives, seen from outside."""

    @abstractmethod
    def drive_endstop(self, motor: int, which: str, level: bool) -> None:
        """The electrical level on an end-stop input (``which``: min or max)."""

    @abstractmethod
    def dir_level(self, motor: int) -> bool:
        """The level on the DIR line."""

    @abstractmethod
    def count_steps(self) -> None:
        """Start counting step pulses from now."""

    @abstractmethod
    def steps(self, motor: int) -> int:
        """Step pulses (rising edges) on the motor's STEP line since :meth:`count_steps`."""

    @abstractmethod
    def bridge(self) -> BridgeState:
        """The H-bridge's state as its input levels show it."""


class MockHarness(Harness):
    name = "mock"
    backend = "mock"
    external = False

    def __init__(self) -> None:
        super().__init__()
        self.world: MockWorld | None = None
        self.mark = 0
        self.lows: tuple[bool, ...] = ()

    def opened(self, spec: HardwareSpec) -> None:
        assert self.hw is not None
        self.world = world_of(self.hw)
        self.world.timeline.events.clear()
        self.lows = tuple(a.endstop_active_low for a in spec.axes)

    def _w(self) -> MockWorld:
        assert self.world is not None
        return self.world

    def drive_pin(self, number: int, level: bool) -> None:
        self._w().pins[number].external = level

    def pin_level(self, number: int) -> bool:
        pin = self._w().pins[number]
        assert pin.is_output
        return pin.read()

    def drive_endstop(self, motor: int, which: str, level: bool) -> None:
        self._w().force_endstop(motor, which, level != self.lows[motor])

    def dir_level(self, motor: int) -> bool:
        events = self._w().timeline.of(EventKind.DIR, motor)
        assert events, "DIR was never set"
        return bool(events[-1].value)

    def count_steps(self) -> None:
        self.mark = len(self._w().timeline.events)

    def steps(self, motor: int) -> int:
        events = list(self._w().timeline.snapshot())[self.mark :]
        return sum(1 for e in events if e.kind == EventKind.STEP and e.index == motor)

    def bridge(self) -> BridgeState:
        bridge = self._w().bridge
        assert bridge is not None
        return bridge.state
