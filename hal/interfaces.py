"""Small typed interfaces between motion logic and hardware.

Each interface follows one pattern: the public method validates and records, the
backend implements one small hook (``_write``, ``_read``, ...). Backends live in
their own modules; nothing here imports a hardware library.
"""

from __future__ import annotations

import enum
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field


class HalError(RuntimeError):
    """A hardware backend could not be loaded or a device could not be opened."""


class Clock(ABC):
    """A monotonic clock in seconds."""

    @abstractmethod
    def now(self) -> float: ...

    @abstractmethod
    def spin_until(self, deadline: float) -> float:
        """Return at ``deadline`` (busy-wait on a real clock); returns the time then."""

    @property
    def is_virtual(self) -> bool:
        return False


class MonotonicClock(Clock):
    """The system's monotonic clock (CLOCK_MONOTONIC via time.perf_counter)."""

    def __init__(self, source: Callable[[], float] = time.perf_counter) -> None:
        self._source = source

    def now(self) -> float:
        return self._source()

    def spin_until(self, deadline: float) -> float:
        source = self._source
        now = source()
        while now < deadline:
            now = source()
        return now


class VirtualClock(Clock):
    """A clock that only moves when told to: deterministic tests."""

    def __init__(self, start: float = 1000.0) -> None:
        self._now = start

    def now(self) -> float:
        return self._now

    def advance_to(self, t: float) -> None:
        if t > self._now:
            self._now = t

    def advance(self, dt: float) -> None:
        self._now += max(0.0, dt)

    def spin_until(self, deadline: float) -> float:
        self.advance_to(deadline)
        return self._now

    @property
    def is_virtual(self) -> bool:
        return True


class Pin(ABC):
    """A general IO pin the host can read, drive and switch between input and output."""

    def __init__(self, number: int, output: bool, level: bool = False) -> None:
        self.number = number
        self._output = output
        self._level = level

    @property
    def is_output(self) -> bool:
        return self._output

    def configure(self, output: bool, level: bool | None = None) -> None:
        """Switch direction; an output starts at ``level`` (default: its last driven level)."""
        if level is not None:
            self._level = level
        self._output = output
        self._configure(output, self._level)

    def write(self, level: bool) -> None:
        if not self._output:
            raise ValueError(f"pin {self.number} is an input")
        self._level = level
        self._write(level)

    def read(self) -> bool:
        """The level on the pin: the driven level of an output, the sensed level of an input."""
        return self._level if self._output else self._read()

    @abstractmethod
    def _configure(self, output: bool, level: bool) -> None: ...

    @abstractmethod
    def _write(self, level: bool) -> None: ...

    @abstractmethod
    def _read(self) -> bool: ...


class InputLine(ABC):
    """An input read as a logic level (end stops)."""

    @abstractmethod
    def read(self) -> bool: ...


class StepPort(ABC):
    """The STEP and DIR lines of one stepper driver.

    ``set_direction`` takes the logical direction (True = counting up); ``invert``
    swaps the wiring. ``pulse`` emits one step pulse and returns the time of the
    rising edge.
    """

    def __init__(self, clock: Clock, invert: bool = False) -> None:
        self.clock = clock
        self.invert = invert
        self.direction: bool | None = None
        self.direction_set_at = float("-inf")

    def set_direction(self, up: bool) -> None:
        if self.direction is up:
            return
        self.direction = up
        try:
            self._write_dir(up != self.invert)
        except BaseException:
            self.direction = None  # the line's level is unknown: write it again next time
            raise
        self.direction_set_at = self.clock.now()

    def pulse(self, width_s: float) -> float:
        if self.direction is None:
            raise RuntimeError("step pulse before a direction was set")
        return self._pulse(width_s)

    @abstractmethod
    def _write_dir(self, level: bool) -> None: ...

    @abstractmethod
    def _pulse(self, width_s: float) -> float: ...


@dataclass(frozen=True)
class DriverStatus:
    """What a stepper driver reports: a fault (None when healthy) and its stall flag."""

    fault: str | None = None
    stall: bool = False


class StepperDriver(ABC):
    """A stepper driver chip's status (over SPI on real hardware)."""

    @abstractmethod
    def status(self) -> DriverStatus: ...


class BridgeState(enum.Enum):
    FORWARD = "forward"
    REVERSE = "reverse"
    BRAKE = "brake"
    COAST = "coast"


class DcBridge(ABC):
    """An H-bridge for one DC motor."""

    def __init__(self) -> None:
        self.state = BridgeState.COAST

    def set(self, state: BridgeState) -> None:
        if state is not self.state:
            self.state = state
            self._apply(state)

    @abstractmethod
    def _apply(self, state: BridgeState) -> None: ...


@dataclass
class StepperHardware:
    """Everything one stepper motor is wired to."""

    port: StepPort
    driver: StepperDriver
    endstop_min: InputLine | None = None
    endstop_max: InputLine | None = None


@dataclass
class Hardware:
    """The whole machine as the motion layer and the daemon see it."""

    clock: Clock
    steppers: list[StepperHardware]
    pins: dict[int, Pin]
    dc: DcBridge | None
    closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        for close in reversed(self.closers):
            close()
        self.closers.clear()
