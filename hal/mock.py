"""Simulated hardware: a world of axes with end stops, wired pins, a DC bridge.

Every mock part subclasses the real interface and records each change with its
timestamp in a shared timeline (gpiozero's MockFactory does the same). Tests can
inject end-stop levels, driver faults and stalls.
"""

from __future__ import annotations

import enum
import threading
from collections import deque
from dataclasses import dataclass
from typing import Any

from motorctl.hal.interfaces import (
    BridgeState,
    Clock,
    DcBridge,
    DriverStatus,
    Hardware,
    InputLine,
    Pin,
    StepperDriver,
    StepperHardware,
    StepPort,
)
from motorctl.hal.spec import AxisSpec, HardwareSpec


class EventKind(enum.StrEnum):
    """What a timeline event records."""

    STEP = "step"  # a step pulse's rising edge; value = the DIR level
    DIR = "dir"  # the DIR line changed; value = the new level
    PIN = "pin"  # an output pin's level was written; value = the level
    CONFIG = "config"  # a pin changed direction; value = True for output
    DC = "dc"  # the DC bridge changed state; value = the BridgeState's value


@dataclass(frozen=True)
class Event:
    """One recorded change: what (``kind``), when (``t``), ``index`` the motor or pin."""

    t: float
    kind: EventKind
    index: int
    value: Any


class Timeline:
    """A bounded record of events (``maxlen=None`` keeps everything, for tests)."""

    def __init__(self, maxlen: int | None = 100_000) -> None:
        self.events: deque[Event] = deque(maxlen=maxlen)
        self.counts: dict[EventKind, int] = {}

    def record(self, t: float, kind: EventKind, index: int, value: Any) -> None:
        self.events.append(Event(t, kind, index, value))
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def of(self, kind: EventKind, index: int | None = None) -> list[Event]:
        return [e for e in self.events if e.kind == kind and (index is None or e.index == index)]

    def step_times(self, motor: int) -> list[float]:
        return [e.t for e in self.of(EventKind.STEP, motor)]


class MockAxis:
    """The mechanics behind one motor: a position counted from the step pulses it got."""

    def __init__(self, spec: AxisSpec) -> None:
        self.spec = spec
        self.position = 0
        self.heading: bool | None = None  # the logical DIR last set (True = up)
        self.fault: str | None = None
        self.forced_stall = False
        self.forced_endstop: dict[str, bool | None] = {"min": None, "max": None}

    def endstop_active(self, which: str) -> bool:
        forced = self.forced_endstop[which]
        if forced is not None:
            return forced
        if which == "min":
            return self.position <= self.spec.endstop_min
        return self.position >= self.spec.endstop_max

    @property
    def stalled(self) -> bool:
        """Pushing past a simulated end stop stalls the motor (as sensorless homing sees it).

        Only while DIR points further past it: a motor backing out is not stalled.
        """
        return (
            self.forced_stall
            or (self.position > self.spec.endstop_max and self.heading is True)
            or (self.position < self.spec.endstop_min and self.heading is False)
        )


class MockStepPort(StepPort):
    def __init__(self, clock: Clock, world: MockWorld, index: int, invert: bool) -> None:
        super().__init__(clock, invert)
        self._world = world
        self._index = index

    def _write_dir(self, level: bool) -> None:
        self._world.raise_injected("dir", self._index)
        self._world.axes[self._index].heading = self.direction
        self._world.timeline.record(self.clock.now(), EventKind.DIR, self._index, level)

    def _pulse(self, width_s: float) -> float:
        clock = self.clock
        self._world.raise_injected("step", self._index)
        rise = clock.now()
        self._world.timeline.record(rise, EventKind.STEP, self._index, self.direction)
        axis = self._world.axes[self._index]
        axis.position += 1 if self.direction else -1
        if clock.is_virtual:
            # A virtual clock does not move for a pulse: the falling edge is implied.
            return rise
        clock.spin_until(rise + width_s)
        return rise


class MockDriver(StepperDriver):
    def __init__(self, axis: MockAxis) -> None:
        self._axis = axis

    def status(self) -> DriverStatus:
        return DriverStatus(fault=self._axis.fault, stall=self._axis.stalled)


class MockEndstop(InputLine):
    def __init__(self, axis: MockAxis, which: str) -> None:
        self._axis = axis
        self._which = which

    def read(self) -> bool:
        active = self._axis.endstop_active(self._which)
        return active != self._axis.spec.endstop_active_low


class MockPin(Pin):
    def __init__(self, world: MockWorld, number: int, output: bool, level: bool) -> None:
        super().__init__(number, output, level)
        self._world = world
        self.external = False  # the level an unwired input senses

    def _configure(self, output: bool, level: bool) -> None:
        now = self._world.clock.now()
        self._world.timeline.record(now, EventKind.CONFIG, self.number, output)
        if output:
            self._world.timeline.record(now, EventKind.PIN, self.number, level)

    def _write(self, level: bool) -> None:
        self._world.raise_injected("pin", self.number)
        now = self._world.clock.now()
        self._world.timeline.record(now, EventKind.PIN, self.number, level)

    def _read(self) -> bool:
        peer = self._world.wired_to(self.number)
        if peer is not None and peer.is_output:
            return peer.read()
        return self.external


class MockBridge(DcBridge):
    def __init__(self, world: MockWorld) -> None:
        super().__init__()
        self._world = world

    def _apply(self, state: BridgeState) -> None:
        self._world.timeline.record(self._world.clock.now(), EventKind.DC, 0, state.value)


class MockWorld:
    """The simulated machine. Build it with :func:`build`; poke it from tests."""

    def __init__(self, spec: HardwareSpec, clock: Clock, timeline_len: int | None) -> None:
        self.clock = clock
        self.lock = threading.Lock()
        self.timeline = Timeline(timeline_len)
        self.axes = [MockAxis(a) for a in spec.axes]
        self.pins: dict[int, MockPin] = {
            p.number: MockPin(self, p.number, p.output, p.initial) for p in spec.pins
        }
        self.line_errors: dict[tuple[str, int], OSError] = {}
        self._wires: dict[int, int] = {}
        for a, b in spec.wires:
            self._wires[a] = b
            self._wires[b] = a
        self.bridge = MockBridge(self) if spec.dc else None

    def wired_to(self, number: int) -> MockPin | None:
        other = self._wires.get(number)
        return None if other is None else self.pins.get(other)

    # -- fault injection -------------------------------------------------
    def inject_fault(self, motor: int, fault: str | None) -> None:
        """Make motor's driver report ``fault`` (None clears it)."""
        self.axes[motor].fault = fault

    def inject_line_error(self, kind: str, index: int, error: OSError | None) -> None:
        """Make every write to a line raise ``error`` (None heals it): ``kind`` is "step" or
        "dir" (``index`` a motor) or "pin" (``index`` a pin number), as a line whose chip went
        away makes gpiod raise."""
        if error is None:
            self.line_errors.pop((kind, index), None)
        else:
            self.line_errors[(kind, index)] = error

    def raise_injected(self, kind: str, index: int) -> None:
        error = self.line_errors.get((kind, index))
        if error is not None:
            raise error

    def inject_stall(self, motor: int, stalled: bool) -> None:
        self.axes[motor].forced_stall = stalled

    def force_endstop(self, motor: int, which: str, active: bool | None) -> None:
        """Force an end stop active/inactive; None returns it to the simulation."""
        self.axes[motor].forced_endstop[which] = active

    # -- persistence of the simulated mechanics ---------------------------
    def snapshot(self) -> dict[str, Any]:
        return {"axes": [a.position for a in self.axes]}

    def restore(self, data: dict[str, Any]) -> None:
        positions = data.get("axes", [])
        for axis, pos in zip(self.axes, positions, strict=False):
            if isinstance(pos, int):
                axis.position = pos

    def hardware(self) -> Hardware:
        steppers = [
            StepperHardware(
                port=MockStepPort(self.clock, self, i, axis.spec.invert_dir),
                driver=MockDriver(axis),
                endstop_min=MockEndstop(axis, "min"),
                endstop_max=MockEndstop(axis, "max"),
            )
            for i, axis in enumerate(self.axes)
        ]
        return MockHardware(self.clock, steppers, dict(self.pins), self.bridge, world=self)


@dataclass
class MockHardware(Hardware):
    """Hardware whose parts are simulated by ``world``."""

    world: MockWorld | None = None


def build(spec: HardwareSpec, clock: Clock) -> Hardware:
    """The mock backend's entry point for :mod:`hal.registry`."""
    timeline_len = spec.options.get("timeline_len", 100_000)
    if timeline_len is not None and not isinstance(timeline_len, int):
        raise ValueError("timeline_len must be an int or None")
    return MockWorld(spec, clock, timeline_len).hardware()


def world_of(hw: Hardware) -> MockWorld:
    """The simulated world behind mock hardware (for tests and the daemon's persistence)."""
    if not isinstance(hw, MockHardware) or hw.world is None:
        raise TypeError("not mock hardware")
    return hw.world
