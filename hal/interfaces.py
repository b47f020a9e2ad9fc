"""Small typed interfaces between motion logic and hardware: what a backend builds.

Over 500 lines on purpose: these are all the parts motion and the daemon use, read in one
place; each interface is short. What a backend is (what the registry builds by name) is in
``contract.py``; the lines a compiled step core may drive in ``compiled_lines.py``.

Each interface follows one pattern: the public method validates and records, the
backend implements one small hook (``_write``, ``_read``, ...). Backends live in
their own packages (``hal/backends/``, the layers in ``hal/layers/``); nothing here imports
a hardware library.

What only some hardware can do is asked for, never found out from a backend's class:

- a capability is an interface of its own that a backend's class also implements
  (:class:`RampDriver`: a driver chip that runs its own ramp); callers ask with
  ``isinstance(driver, RampDriver)``;
- what every part has, but only some have something of, is a method with a neutral default
  here (:meth:`StepperDriver.stats`, :meth:`Hardware.persistent_state`).
"""

from __future__ import annotations

import enum
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from motorctl.hal.compiled_lines import (
    NO_COMPILED_LINES,
    ChardevLines,
    CompiledLines,
    SimulatedLines,
)

if TYPE_CHECKING:  # they import this module; a backend makes them for its Hardware
    from motorctl.hal.poller import DriverPoller
    from motorctl.hal.spi import SpiBuses, SpiFactory


class HalError(RuntimeError):
    """A hardware backend could not be loaded or a device could not be opened.

    The message names the device/line and the fix; the daemon prints it and exits.
    """


class HalIOError(HalError):
    """A device failed while running (a gpiod/SPI call raised ``OSError``, ...).

    Backends raise this (and only this) from run-time calls. The step executor latches it as a
    fault of the motors concerned (E4, position lost) and keeps running; it never kills a
    thread or process.
    """


class Clock(ABC):
    """A monotonic clock in seconds."""

    @abstractmethod
    def now(self) -> float: ...

    @abstractmethod
    def spin_until(self, deadline: float) -> float:
        """Return at ``deadline`` (busy-wait on a real clock); returns the time then."""

    def now_ns(self) -> int:
        """The time in integer nanoseconds (the step path's ticks)."""
        return round(self.now() * 1_000_000_000)

    @property
    def is_virtual(self) -> bool:
        return False


class MonotonicClock(Clock):
    """The system's monotonic clock (CLOCK_MONOTONIC via time.perf_counter)."""

    def __init__(
        self,
        source: Callable[[], float] = time.perf_counter,
        source_ns: Callable[[], int] | None = None,
    ) -> None:
        self._source = source
        if source_ns is None and source is time.perf_counter:
            source_ns = time.perf_counter_ns
        if source_ns is not None:
            self.now_ns = source_ns  # type: ignore[method-assign]  # the C function itself

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


@dataclass(frozen=True)
class Edge:
    """One edge on an input line, as the kernel timestamped it.

    ``line`` indexes :attr:`EdgeInputs.names`; ``active`` is the logical level after the edge
    (polarity already applied: True = the switch is pressed); ``t`` is on the executor's
    clock (CLOCK_MONOTONIC seconds on real hardware, the virtual clock in tests).
    """

    line: int
    active: bool
    t: float


class StepOutputs(ABC):
    """The STEP and DIR lines of every motor one step executor drives, in one request.

    Owned by exactly one thread (the executor's); nothing here is thread-safe. Motors are
    indexed 0..n-1 as in the spec the outputs were built from.

    - :meth:`pulse` raises the STEP lines of several motors whose edges fall on the same tick
      in ONE backend call (gpiod v2 ``set_values``), holds them ``width_s``, lowers them in
      one call, and returns the time right after the rising edge was written (an upper
      bound of the edge's time). :meth:`rise` and :meth:`fall` are its two halves, for a
      caller that works while the lines are high.
    - :meth:`set_direction` honours the DIR hold time after the last STEP fall before it
      changes DIR, and records when a step may follow (:attr:`ready_at`: the set-up time).
      The executor never raises a STEP before ``ready_at[motor]``.
    - Error contract: a backend hook that fails at run time raises :class:`HalIOError` (never
      a bare ``OSError``); the executor turns it into a latched fault, never a dead thread.

    Backends implement three hooks: ``_write_dir``, ``_write_steps`` and ``_close``.
    """

    def __init__(
        self,
        clock: Clock,
        invert_dir: Sequence[bool],
        dir_setup_s: Sequence[float],
        dir_hold_s: Sequence[float],
    ) -> None:
        n = len(invert_dir)
        if not len(dir_setup_s) == len(dir_hold_s) == n:
            raise ValueError("one invert/setup/hold value per motor")
        self.clock = clock
        self.invert_dir = list(invert_dir)
        self.dir_setup_s = list(dir_setup_s)
        self.dir_hold_s = list(dir_hold_s)
        self.direction: list[bool | None] = [None] * n
        self.ready_at = [float("-inf")] * n
        self.last_fall = [float("-inf")] * n

    @property
    def motors(self) -> int:
        return len(self.invert_dir)

    def set_direction(self, motor: int, up: bool) -> None:
        """Set DIR to the logical direction ``up`` (True = counting up); no-op if already so."""
        if self.direction[motor] is up:
            return
        clock = self.clock
        hold = self.last_fall[motor] + self.dir_hold_s[motor]
        if clock.now() < hold:
            clock.spin_until(hold)
        self.direction[motor] = None  # unknown until the write succeeded
        self._write_dir(motor, up != self.invert_dir[motor])
        self.direction[motor] = up
        self.ready_at[motor] = clock.now() + self.dir_setup_s[motor]

    def pulse(self, motors: Sequence[int], width_s: float) -> float:
        """One STEP pulse on every motor in ``motors`` at once; returns the rising edge's time."""
        rise = self.rise(motors)
        self.fall(motors, rise + round(width_s * 1_000_000_000))
        return rise / 1_000_000_000

    def rise(self, motors: Sequence[int]) -> int:
        """Raise the STEP lines of ``motors`` in one call; returns the time (ns) right after.

        The step executor does its accounting while the lines are high, then calls
        :meth:`fall` with the end of the pulse width.
        """
        direction = self.direction
        for m in motors:
            if direction[m] is None:
                raise RuntimeError(f"step pulse on motor {m} before a direction was set")
        self._write_steps(motors, True)
        # the edge happened by now: spacing the next one from this upper bound keeps real
        # edges at least the profile's interval apart even if we were preempted in between
        return self.clock.now_ns()

    def fall(self, motors: Sequence[int], not_before_ns: int) -> None:
        """Lower the STEP lines of ``motors`` in one call, not before ``not_before_ns``."""
        clock = self.clock
        if not clock.is_virtual:
            now_ns = clock.now_ns
            while now_ns() < not_before_ns:
                pass
        self._write_steps(motors, False)
        fall = clock.now()
        last_fall = self.last_fall
        for m in motors:
            last_fall[m] = fall

    def close(self) -> None:
        """Release the lines (STEP low); idempotent."""
        self._close()

    @abstractmethod
    def _write_dir(self, motor: int, level: bool) -> None:
        """Drive motor's DIR line to the physical ``level``."""

    @abstractmethod
    def _write_steps(self, motors: Sequence[int], level: bool) -> None:
        """Drive the STEP lines of ``motors`` to ``level`` in one call."""

    def _close(self) -> None:
        return None


class EdgeInputs(ABC):
    """Input lines (end stops, ...) read as kernel-timestamped edges, never polled per step.

    Owned by one thread (the executor's). :meth:`read_edges` never blocks: it returns the
    edges pending since the last call, oldest first (empty when none). :meth:`level` is the
    current logical level of a line. ``fileno`` is a descriptor that becomes readable when
    edges are pending (None when the backend has none; then the caller just calls
    :meth:`read_edges`). Run-time failures raise :class:`HalIOError`.
    """

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)

    @abstractmethod
    def read_edges(self) -> list[Edge]: ...

    @abstractmethod
    def level(self, line: int) -> bool: ...

    def fileno(self) -> int | None:
        return None

    def close(self) -> None:
        return None


@dataclass
class StepIO:
    """What a step executor owns: STEP/DIR outputs, end-stop inputs, the clock they share.

    ``endstops[motor]`` is ``(min_line, max_line)``: indexes into ``inputs`` (None: not wired).
    Its motors are the spec's ``stepped()`` axes, in order (a TMC5160 that runs its own ramp
    is not a step executor's motor).
    Built by :func:`motorctl.hal.registry.open_step_io` from a picklable spec, in the process
    that uses it (a child process cannot inherit a gpiod request).

    ``compiled``: the optional capability "lines a compiled core may drive"
    (:data:`~motorctl.hal.compiled_lines.CompiledLines`: the same lines as raw kernel
    requests, or a simulated machine's; ``Backend.compiled_lines`` in contract.py gives
    them), None when the backend has none to give; then ``compiled_missing`` says why. A
    compiled core that takes them owns them until it stops (the Python parts above are not
    called meanwhile).
    """

    clock: Clock
    outputs: StepOutputs
    inputs: EdgeInputs
    endstops: tuple[tuple[int | None, int | None], ...]
    closers: list[Callable[[], None]] = field(default_factory=list)
    compiled: CompiledLines | None = None
    compiled_missing: str = NO_COMPILED_LINES

    def close(self) -> None:
        for close in reversed(self.closers):
            close()
        self.closers.clear()
        self.outputs.close()
        self.inputs.close()

    def set_compiled(self, lines: CompiledLines | str) -> None:
        """What the backend offers a compiled core (``Backend.compiled_lines``): its lines,
        or why there are none."""
        if isinstance(lines, str):
            self.compiled, self.compiled_missing = None, lines
        else:
            self.compiled = lines

    def compiled_text(self) -> str:
        """What the StepIO offers a compiled core, in words (``motorctld --probe``)."""
        lines = self.compiled
        if isinstance(lines, ChardevLines):
            apis = sorted({f"v{r.uapi}" for r in (*lines.outputs, *lines.inputs)})
            return (
                f"GPIO character-device requests (uAPI {', '.join(apis)}): "
                f"{len(lines.outputs)} for STEP/DIR, {len(lines.inputs)} for end stops"
            )
        if isinstance(lines, SimulatedLines):
            return "the simulated mechanics of the mock"
        return f"none ({self.compiled_missing})"


@dataclass(frozen=True)
class DriverStatus:
    """What a stepper driver reports: a fault (None when healthy) and its stall flag."""

    fault: str | None = None
    stall: bool = False


class StepperDriver(ABC):
    """A stepper driver chip's status (over SPI on real hardware).

    :meth:`status` is the latest reading, without I/O (any thread); :meth:`refresh` reads
    the chip, on the HAL's driver poller's thread (hal/poller.py), never on the step path.
    """

    @abstractmethod
    def status(self) -> DriverStatus: ...

    def refresh(self) -> DriverStatus:
        """Read the chip now and return what :meth:`status` then says (the driver poller's
        thread; may block on its bus; a failed read is a fault in the status, not an
        exception). Default: :meth:`status`, for a driver with nothing to read."""
        return self.status()

    def stats(self) -> dict[str, object] | None:
        """The driver's figures for the status document's ``drivers`` list (docs/status.md:
        polls, SPI status flags, fault and warning counts), read without I/O from any
        thread; None (the default): a driver with nothing to report."""
        return None


@dataclass(frozen=True)
class RampStatus:
    """A :class:`RampDriver`'s ramp as one read gave it.

    ``position``: the driver's step counter (steps of the configured microstep resolution);
    ``velocity``: step/s, signed. Its reference switches, by side (``min``: below, direction
    -1; ``max``: above, +1): ``active``, the switch's level now; ``stopped``, the switch
    stopped the motor (an event, kept until the next :meth:`RampDriver.watch`);
    ``latched``, the position at the switch's edge that :meth:`RampDriver.watch` armed (its
    active edge, or its inactive one for a release) is latched
    (:meth:`RampDriver.latched_position`). ``stall_stopped``: stallGuard stopped the motor.
    ``settled``: the chip ended the last motion it was given where it stands, short of or
    past its target, on purpose (a dSPIN cannot take a new target while it ramps, so it
    stops along DEC instead; a ReleaseSW that ran its whole way is stopped there; a run
    is stopped at the end of the chip's position counter, which would wrap past it): that
    motion is done.
    """

    position: int
    velocity: float
    active_min: bool = False
    active_max: bool = False
    stopped_min: bool = False
    stopped_max: bool = False
    latched_min: bool = False
    latched_max: bool = False
    stall_stopped: bool = False
    settled: bool = False

    def switch_active(self, direction: int) -> bool:
        """The level of the switch on the side of ``direction`` (+1: max, -1: min)."""
        return self.active_max if direction > 0 else self.active_min

    def switch_stopped(self, direction: int) -> bool:
        return self.stopped_max if direction > 0 else self.stopped_min

    def latched(self, direction: int) -> bool:
        return self.latched_max if direction > 0 else self.latched_min


class RampDriver(ABC):
    """The capability of a driver chip that runs its own ramp (a TMC5160 in
    motion-controller mode): it moves its motor itself, with no STEP/DIR lines; an executor
    (``motion/executors/chip_ramp.py``) hands it targets, speeds and ramps, and reads back
    where it is. Asked for with ``isinstance(stepper.driver, RampDriver)``.

    Positions are the driver's step counter (steps of the configured microstep resolution),
    speeds step/s, accelerations step/s^2 (positive), directions +1 (up) or -1 (down). Each
    call is a few bus transfers from the thread of the executor that owns the motor (the
    planner, the motion engine's lock held); a failure raises :class:`HalError`, which the
    executor makes a fault of the motor.
    """

    name: str
    #: how often its executor reads it while a motion runs, and at rest (s): the defaults of
    #: [spidev] ramp_poll_ms and ramp_idle_poll_ms
    poll_s: float = 0.005
    idle_poll_s: float = 0.05
    #: resets of the chip seen while running: each one lost the position
    resets: int = 0

    @abstractmethod
    def ramp_status(self) -> RampStatus:
        """Where the motor is and how fast it goes, the switches and stops: one read."""

    def command_status(self) -> RampStatus:
        """:meth:`ramp_status` read for a command: the executor asks it where the engine
        plans the motor's next motion from (``committed()``), and :meth:`watch` and the
        command follow at once, with no other call to this driver in between (unless the
        plan turns out to be no motion). A driver whose :meth:`watch` or command has to
        read the chip anyway may make this one read serve them (a dSPIN: the GetStatus that
        clears the old motion's latched switch event, and STATUS and ABS_POS for GoTo_DIR);
        by default, :meth:`ramp_status`."""
        return self.ramp_status()

    @abstractmethod
    def latched_position(self) -> int:
        """The position the reference switch latched at the edge :meth:`watch` armed."""

    @abstractmethod
    def watch(self, direction: int, stall: bool = False, release: int = 0) -> None:
        """Arm the stops for the next motion: the reference switch ahead in ``direction``
        (+1, -1; 0: none) stops the motor at once and latches the position at its active
        edge; ``stall``: stallGuard stops it; ``release`` (+1, -1; 0: none): the switch on
        that side latches the position at its inactive edge, where it releases (it stops
        nothing: homing's back-off, whose executor stops there). Old events and latches are
        cleared."""

    @abstractmethod
    def move_to(self, target: int, speed: float, acc: float, dec: float) -> None:
        """Run a trapezoid to ``target``: up to ``speed``, ramps ``acc`` and ``dec``."""

    @abstractmethod
    def run(self, direction: int, speed: float, acc: float) -> None:
        """Accelerate with ``acc`` to ``speed`` in ``direction`` and keep going."""

    @abstractmethod
    def stop(self, dec: float | None) -> None:
        """Stop along ``dec``, or as hard as the chip can (``None``)."""

    @abstractmethod
    def report_stall_stop(self) -> bool:
        """The executor saw stallGuard stop the motor: from now until the next
        :meth:`watch` the driver's :meth:`StepperDriver.status` reports a stall. True the
        first time (not yet reported)."""


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
    """What of one stepper motor the daemon's process owns: its driver chip.

    STEP/DIR and end stops belong to the step executor (:class:`StepIO`).
    """

    driver: StepperDriver


@dataclass
class Hardware:
    """The machine as the daemon's process sees it: drivers, pins, DC bridge, and what its
    parts share: the driver poller (``poller``: every layer and backend registers the chips
    it reads there, the motion engine takes what they report) and the SPI buses (``spi``:
    one per device node, whichever layer uses it).

    The step/dir/end-stop lines are not here: the step executor opens them itself
    (:func:`motorctl.hal.registry.open_step_io`).
    """

    clock: Clock
    steppers: list[StepperHardware]
    pins: dict[int, Pin]
    dc: DcBridge | None
    poller: DriverPoller
    spi: SpiBuses
    closers: list[Callable[[], None]] = field(default_factory=list)
    #: what an executor in another process must add to the spec's options to open its
    #: step IO consistently with this hardware (the mock: its shared mechanics)
    step_io_options: dict[str, object] = field(default_factory=dict)
    #: whether a late step may have cost a motor steps (a real rotor); False for simulated
    #: motors, whose lateness is counted but never a fault (docs/timing.md)
    motors_lose_steps: bool = True
    #: descriptors that executor's process gets for it, each as the option of that name
    #: (the mock's shared mechanics): its own copy, under a number of its own
    step_io_fds: dict[str, int] = field(default_factory=dict)
    #: py-spidev's API for the SPI devices a backend simulates (the mock's dSPIN chains):
    #: the layers open their nodes with it; None: the kernel's, through py-spidev
    spi_factory: SpiFactory | None = None

    def persistent_state(self) -> dict[str, Any]:
        """What of the machine lives and dies with the daemon's state file (saved with it,
        under keys of the backend's own): a simulated machine's axis positions. Real
        hardware keeps nothing there: ``{}`` (the default)."""
        return {}

    def restore_persistent_state(self, saved: dict[str, Any]) -> None:
        """Take back what :meth:`persistent_state` gave, from ``saved`` (the state file's
        other keys; ones that are not the backend's are ignored). The default: nothing."""
        return None

    def open_alert_lines(self, uses: Sequence[tuple[str, str]]) -> EdgeInputs:
        """Inputs a layer reads as edges in this process: the open-drain, active-low
        outputs of its chips (a dSPIN's FLAG and BUSY), one per ``(use, line)`` (``use``
        names it in messages, ``line`` is the config's line text), pulled up; an
        :class:`Edge` is ``active`` when the line falls (low: the chip signals). Closed
        with the Hardware. The default: a backend without GPIO inputs refuses them."""
        names = ", ".join(use for use, _ in uses)
        raise HalError(f"{names}: this hardware backend has no GPIO inputs to read them on")

    def close(self) -> None:
        """Stop the poller (nothing reads a chip any more), then close the parts."""
        self.poller.stop()
        for close in reversed(self.closers):
            close()
        self.closers.clear()
