"""The simulated machine of the mock backend: a world of axes with end stops, wired pins, a
DC bridge.

Over 500 lines on purpose: one simulated machine whose parts (axes, step outputs, edge
inputs, pins, bridge) share its cells and timeline, as the real parts share one board.

Every mock part subclasses the real interface and records each change with its
timestamp in a shared timeline (gpiozero's MockFactory does the same). Tests can
inject end-stop levels, driver faults and stalls. The simulated end stops and the wires
come from the mock's own config sections in the spec (``[motors.mock]``, ``[mock]``:
``config.py``). The backend's entry (``backend.py``) builds a world from a spec.
"""

from __future__ import annotations

import enum
import json
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from motorctl.hal.backends.mock.config import (
    ENDSTOP_MAX,
    ENDSTOP_MIN,
    MockAxisConfig,
    MockConfig,
    motors_lose_steps,
)
from motorctl.hal.backends.mock.dspin_world import MockSpiNodes, factory_of
from motorctl.hal.compiled_lines import SimulatedLines
from motorctl.hal.interfaces import (
    BridgeState,
    Clock,
    DcBridge,
    DriverStatus,
    Edge,
    EdgeInputs,
    HalIOError,
    Hardware,
    Pin,
    StepIO,
    StepOutputs,
    StepperDriver,
    StepperHardware,
)
from motorctl.hal.poller import DriverPoller
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.hal.spi import SpiBuses
from motorctl.schema import default_of


class EventKind(enum.StrEnum):
    """What a timeline event records."""

    STEP = "step"  # a step pulse's rising edge; value = the logical direction (True = up)
    DIR = "dir"  # the DIR line changed; value = the new level
    PIN = "pin"  # an output pin's level was written; value = the level
    CONFIG = "config"  # a pin changed direction; value = True for output
    DC = "dc"  # the DC bridge changed state; value = the BridgeState's value


class Event(NamedTuple):
    """One recorded change: what (``kind``), when (``t``), ``index`` the motor or pin.

    A named tuple: the step path records one per STEP edge, and a tuple is made fast.
    """

    t: float
    kind: EventKind
    index: int  # type: ignore[assignment]  # shadows tuple.index: the field's name
    value: Any


class Timeline:
    """A bounded record of events (``maxlen=None`` keeps everything, for tests)."""

    def __init__(self, maxlen: int | None = 100_000) -> None:
        self.events: deque[Event] = deque(maxlen=maxlen)
        self.counts: dict[EventKind, int] = {}
        # The executor records while tests and status read: copying a deque is not atomic
        # (a collection during the copy can switch threads: "deque mutated during
        # iteration"), so both sides take this lock for a few hundred nanoseconds.
        self._lock = threading.Lock()

    def record(self, t: float, kind: EventKind, index: int, value: Any) -> None:
        with self._lock:
            self.events.append(Event(t, kind, index, value))
            self.counts[kind] = self.counts.get(kind, 0) + 1

    def record_steps(self, t: float, motors: Sequence[int], ups: Sequence[bool | None]) -> None:
        """One STEP event per motor in ``motors`` at ``t`` (the step path: one lock)."""
        step = EventKind.STEP
        with self._lock:
            append = self.events.append
            for m in motors:
                append(Event(t, step, m, ups[m]))
            self.counts[step] = self.counts.get(step, 0) + len(motors)

    def snapshot(self) -> tuple[Event, ...]:
        with self._lock:
            return tuple(self.events)

    def of(self, kind: EventKind, index: int | None = None) -> list[Event]:
        return [
            e for e in self.snapshot() if e.kind == kind and (index is None or e.index == index)
        ]

    def step_times(self, motor: int) -> list[float]:
        return [e.t for e in self.of(EventKind.STEP, motor)]


_POSITION, _HEADING, _FORCED_MIN, _FORCED_MAX, _FORCED_STALL, _GEN, _PUSHED = range(7)
_FIELDS = 7
_UNSET, _OFF, _ON = 0, 1, 2


class MockAxis:
    """The mechanics behind one motor: a position moved by the step pulses it got, between
    two end stops (``[motors.mock]``, docs/config.md): at ``endstop_min`` and ``endstop_max``
    a switch, active there and beyond, none without ``switches``; a hard stop there too: a
    pulse that would take the axis further out is lost, and the driver reports a stall
    while the motor keeps pushing that way (what stall homing finds).

    The state lives in seven int64 slots of ``cells``: a private buffer, or a slice of a
    shared-memory block when the step executor runs in a process of its own (the machine
    is one physical thing that both processes touch). Writes are single 8-byte stores.
    """

    def __init__(self, spec: AxisSpec, cells: memoryview) -> None:
        self.spec = spec
        ends = spec.sections.get(MockAxisConfig)  # [motors.mock]: where the end stops sit
        self.endstop_min: int = ENDSTOP_MIN if ends is None else ends.endstop_min
        self.endstop_max: int = ENDSTOP_MAX if ends is None else ends.endstop_max
        self.switches: bool = True if ends is None else ends.switches
        self._c = cells
        self.fault: str | None = None  # the driver chip's fault: the daemon's process only

    @property
    def cells(self) -> memoryview:
        """The seven int64 slots (the step path reads them directly)."""
        return self._c

    def detach(self) -> None:
        """Keep the state in a private buffer from now on (the shared block is closing)."""
        old = self._c
        self._c = memoryview(bytearray(old.tobytes())).cast("q")
        old.release()

    @property
    def position(self) -> int:
        return int(self._c[_POSITION])

    @position.setter
    def position(self, value: int) -> None:
        self._c[_POSITION] = value

    def step(self, delta: int) -> None:
        """A STEP pulse moves the axis by ``delta`` (the step path: two 8-byte stores), unless
        it pushes it against a hard stop: then it is lost, and the axis pushed."""
        c = self._c
        p = c[_POSITION]
        if p >= self.endstop_max if delta > 0 else p <= self.endstop_min:
            c[_PUSHED] = 1
            return
        c[_POSITION] = p + delta
        c[_PUSHED] = 0

    @property
    def heading(self) -> bool | None:
        """The logical DIR last set (True = up), None before the first."""
        h = self._c[_HEADING]
        return None if h == 0 else h == 1

    @heading.setter
    def heading(self, up: bool | None) -> None:
        self._c[_HEADING] = 0 if up is None else (1 if up else 2)

    @property
    def forced_stall(self) -> bool:
        return bool(self._c[_FORCED_STALL])

    @forced_stall.setter
    def forced_stall(self, value: bool) -> None:
        self._c[_FORCED_STALL] = int(value)

    @property
    def generation(self) -> int:
        """Bumped whenever a test forces an end stop: inputs re-read their levels then."""
        return int(self._c[_GEN])

    def force(self, which: str, active: bool | None) -> None:
        slot = _FORCED_MIN if which == "min" else _FORCED_MAX
        self._c[slot] = _UNSET if active is None else (_ON if active else _OFF)
        self._c[_GEN] = self._c[_GEN] + 1

    def endstop_active(self, which: str) -> bool:
        return self.endstop_at(which, self.position)

    def endstop_at(self, which: str, position: int) -> bool:
        """The end stop's level were the axis at ``position`` (forced levels included)."""
        forced = self._c[_FORCED_MIN if which == "min" else _FORCED_MAX]
        if forced != _UNSET:
            return bool(forced == _ON)
        if not self.switches:
            return False
        if which == "min":
            return position <= self.endstop_min
        return position >= self.endstop_max

    @property
    def stalled(self) -> bool:
        """Pushing against a hard stop stalls the motor (as sensorless homing sees it): a
        pulse was lost there and DIR still points into it (a motor backing out, or one that
        came back to the stop without pushing, is not stalled)."""
        if self.forced_stall:
            return True
        if not self._c[_PUSHED]:
            return False
        p = self.position
        return (p >= self.endstop_max and self.heading is True) or (
            p <= self.endstop_min and self.heading is False
        )


class MockStepOutputs(StepOutputs):
    """STEP/DIR of the stepped axes: each STEP rise is a "step" event and moves the axis.

    Motor ``m`` is world axis ``axes[m]`` (``spec.stepped()``); the timeline and the world
    use the world's axis numbers."""

    def __init__(
        self, world: MockWorld, inputs: MockEdgeInputs, stepped: Sequence[int] | None = None
    ) -> None:
        self._axis_of = list(range(len(world.axes)) if stepped is None else stepped)
        self._identity = self._axis_of == list(range(len(world.axes)))
        axes = [world.axes[g].spec for g in self._axis_of]
        super().__init__(
            world.clock,
            [a.invert_dir for a in axes],
            [a.dir_setup_s for a in axes],
            [a.dir_hold_s for a in axes],
        )
        self.world = world
        self._inputs = inputs

    @property
    def axes(self) -> tuple[int, ...]:
        """The world's axis of each motor."""
        return tuple(self._axis_of)

    def _write_dir(self, motor: int, level: bool) -> None:
        axis = self._axis_of[motor]
        self.world.raise_injected("dir", axis)
        self.world.axes[axis].heading = level != self.invert_dir[motor]
        self.world.timeline.record(self.clock.now(), EventKind.DIR, axis, level)

    def _write_steps(self, motors: Sequence[int], level: bool) -> None:
        direction: Sequence[bool | None] = self.direction
        if not self._identity:  # some axes are not stepped (a TMC5160 runs its own ramp)
            axis_of = self._axis_of
            ups: list[bool | None] = [None] * len(self.world.axes)
            for m in motors:
                ups[axis_of[m]] = direction[m]
            motors, direction = [axis_of[m] for m in motors], ups  # world axis numbers
        world = self.world
        if world.line_errors:
            for m in motors:
                world.raise_injected("step", m)
        if not level:
            return
        t = self.clock.now()
        world.timeline.record_steps(t, motors, direction)
        axes, moved = world.axes, self._inputs.moved
        for m in motors:
            axes[m].step(1 if direction[m] else -1)
            moved(m, t)


class MockEdgeInputs(EdgeInputs):
    """Both end stops of every axis (line 2*i: min, 2*i + 1: max), as logical levels.

    A step that moves an axis onto or off a simulated end stop queues an edge at the
    step's time; a forced level (``MockWorld.force_endstop``) or a position set by hand is
    seen at the next read, with that read's time.
    """

    def __init__(self, world: MockWorld) -> None:
        super().__init__([f"axis{i}.{w}" for i in range(len(world.axes)) for w in ("min", "max")])
        self._world = world
        self._levels = [self._sense(line) for line in range(len(self.names))]
        self._axes = world.axes
        self._seen_gen = [a.generation for a in world.axes]
        self._seen_pos = [a.position for a in world.axes]
        self._pending: deque[Edge] = deque()

    def _sense(self, line: int) -> bool:
        return self._world.axes[line // 2].endstop_active("max" if line % 2 else "min")

    def _update(self, line: int, t: float) -> None:
        now = self._sense(line)
        if now != self._levels[line]:
            self._levels[line] = now
            self._pending.append(Edge(line, now, t))

    def moved(self, axis: int, t: float) -> None:
        c = self._axes[axis].cells
        self._seen_gen[axis] = c[_GEN]
        self._seen_pos[axis] = c[_POSITION]
        self._update(2 * axis, t)
        self._update(2 * axis + 1, t)

    def _refresh(self) -> None:
        """Levels a test changed behind the step path's back (forced, or moved by hand)."""
        seen_gen, seen_pos = self._seen_gen, self._seen_pos
        for i, axis in enumerate(self._axes):
            c = axis.cells
            if c[_GEN] != seen_gen[i] or c[_POSITION] != seen_pos[i]:
                self.moved(i, self._world.clock.now())

    def read_edges(self) -> list[Edge]:
        self._refresh()
        out = list(self._pending)
        self._pending.clear()
        return out

    def level(self, line: int) -> bool:
        self._refresh()
        return self._levels[line]


class MockDriver(StepperDriver):
    def __init__(self, axis: MockAxis) -> None:
        self._axis = axis

    def status(self) -> DriverStatus:
        return DriverStatus(fault=self._axis.fault, stall=self._axis.stalled)


class MockPin(Pin):
    def __init__(self, world: MockWorld, number: int, output: bool, level: bool) -> None:
        super().__init__(number, output, level)
        self._world = world
        self.external = False  # the level an unwired input senses

    def _configure(self, output: bool, level: bool) -> None:
        self._world.timeline.record(self._world.clock.now(), EventKind.CONFIG, self.number, output)
        if output:
            self._world.timeline.record(self._world.clock.now(), EventKind.PIN, self.number, level)

    def _write(self, level: bool) -> None:
        self._world.raise_injected("pin", self.number)
        self._world.timeline.record(self._world.clock.now(), EventKind.PIN, self.number, level)

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
    """The simulated machine. Build it with :func:`build`; poke it from tests.

    Owned by the daemon's process; its axes' mechanics may be shared (``share``: an anonymous
    shared block, :mod:`motorctl.hal.shm`) with the step executor's process, which gets a
    copy of its descriptor (``mechanics``), then has a world of its own over the same
    mechanics and keeps its own timeline (written to ``timeline_file``, JSON lines, when its
    step IO closes).
    """

    def __init__(
        self,
        spec: HardwareSpec,
        clock: Clock,
        timeline_len: int | None,
        *,
        share: bool = False,
        mechanics: int | None = None,
    ) -> None:
        self.spec = spec
        self.clock = clock
        self.lock = threading.Lock()
        self.timeline = Timeline(timeline_len)
        size = max(1, len(spec.axes)) * _FIELDS * 8
        self._shm: SharedBlock | None = None
        if mechanics is not None:
            self._shm = SharedBlock.attach(mechanics, size, "motorctl-mock-mechanics")
            buf = self._shm.buf
        elif share:  # zero-filled
            self._shm = SharedBlock.create(size, "motorctl-mock-mechanics")
            buf = self._shm.buf
        else:
            buf = memoryview(bytearray(size))
        self._cells = buf.cast("q")
        self.axes = [
            MockAxis(a, self._cells[i * _FIELDS : (i + 1) * _FIELDS])
            for i, a in enumerate(spec.axes)
        ]
        self.pins: dict[int, MockPin] = {
            p.number: MockPin(self, p.number, p.output, p.initial) for p in spec.pins
        }
        self.line_errors: dict[tuple[str, int], OSError] = {}
        self._wires: dict[int, int] = {}
        world = spec.sections.get(MockConfig)
        for a, b in world.wires if isinstance(world, MockConfig) else ():
            self._wires[a] = b
            self._wires[b] = a
        self.bridge = MockBridge(self) if spec.dc else None
        #: the dSPIN chains the axes' [motors.dspin] name (built with the hardware)
        self.spi_nodes: MockSpiNodes | None = None

    @property
    def mechanics(self) -> int | None:
        """The shared mechanics' descriptor (for the executor's process to inherit), when
        they are shared and this world created them."""
        return None if self._shm is None else self._shm.fd

    def close(self) -> None:
        if self._shm is None:
            return
        for a in self.axes:  # the same axes (drivers hold them) move to private copies
            a.detach()
        self._cells.release()
        self._shm.close()
        self._shm = None

    def dump_timeline(self, path: str) -> None:
        with open(path, "w", encoding="utf-8") as f:
            for e in self.timeline.snapshot():
                f.write(json.dumps([e.t, e.kind, e.index, e.value]) + "\n")

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
        away makes gpiod raise. Step and DIR lines raise it as the HalIOError of the contract
        (in this process's world: the executor's own process has a world of its own)."""
        if error is None:
            self.line_errors.pop((kind, index), None)
        else:
            self.line_errors[(kind, index)] = error

    def raise_injected(self, kind: str, index: int) -> None:
        error = self.line_errors.get((kind, index))
        if error is None:
            return
        if kind == "pin":
            raise error
        raise HalIOError(f"motor {index} {kind.upper()} line: {error}") from error

    def inject_stall(self, motor: int, stalled: bool) -> None:
        self.axes[motor].forced_stall = stalled

    def force_endstop(self, motor: int, which: str, active: bool | None) -> None:
        """Force an end stop active/inactive; None returns it to the simulation."""
        self.axes[motor].force(which, active)

    # -- persistence of the simulated mechanics ---------------------------
    def snapshot(self) -> dict[str, Any]:
        return {"axes": [a.position for a in self.axes]}

    def restore(self, data: dict[str, Any]) -> None:
        """Axis positions from a state file: what is not a list of integers an axis can
        hold is left out (the file may hold anything)."""
        positions = data.get("axes", [])
        if not isinstance(positions, list):
            return
        for axis, pos in zip(self.axes, positions, strict=False):
            if isinstance(pos, int) and not isinstance(pos, bool) and abs(pos) < 1 << 62:
                axis.position = pos

    def hardware(self) -> Hardware:
        """The daemon's part; each simulated driver is read by the driver poller (a fault
        or stall injected here reaches the motors at its next poll)."""
        steppers = [StepperHardware(driver=MockDriver(axis)) for axis in self.axes]
        poller = DriverPoller(self.clock)
        for i, (stepper, axis) in enumerate(zip(steppers, self.spec.axes, strict=True)):
            poller.watch(stepper.driver, f"{axis.name or f'motor {i}'} (mock driver)")
        hw = MockHardware(
            self.clock, steppers, dict(self.pins), self.bridge, poller, SpiBuses(), world=self
        )
        hw.motors_lose_steps = motors_lose_steps(self.spec)
        self.spi_nodes = factory_of(self.spec, self.axes, self.clock)
        hw.spi_factory = self.spi_nodes
        if self.mechanics is not None:
            hw.step_io_fds["mechanics"] = self.mechanics
        hw.closers.append(self.close)
        return hw

    def step_io(self) -> StepIO:
        """The step executor's part: the axes ``spec.stepped()`` names (the end-stop inputs
        cover every axis; line 2*i is axis i's min)."""
        stepped = self.spec.stepped()
        inputs = MockEdgeInputs(self)
        outputs = MockStepOutputs(self, inputs, stepped)
        ends = tuple((2 * i, 2 * i + 1) for i in stepped)
        return StepIO(self.clock, outputs, inputs, ends)

    def simulated_lines(self, stepped: tuple[int, ...]) -> SimulatedLines:
        """The lines a compiled core may drive for the motors of axes ``stepped``: these
        mechanics and this timeline, for the compiled step core's counterpart of the parts
        here."""
        return SimulatedLines(
            self._cells,
            tuple((a.endstop_min, a.endstop_max) for a in self.axes),
            tuple(a.switches for a in self.axes),
            stepped,
            self.timeline.events.maxlen,
            self._record_compiled,
            self._compiled_line_errors,
        )

    def _record_compiled(self, edges: list[tuple[int, int, int, int, int]]) -> None:
        """The compiled core's simulated edges into the timeline: (t ns, 0 step or 1 dir,
        axis, value, rise call)."""
        kinds = (EventKind.STEP, EventKind.DIR)
        record = self.timeline.record
        for t, kind, axis, value, _call in edges:
            record(t / 1e9, kinds[kind], axis, bool(value))

    def _compiled_line_errors(self) -> dict[tuple[str, int], str]:
        """The STEP/DIR writes that fail now, as the text of the HalIOError they raise."""
        return {
            (kind, index): f"motor {index} {kind.upper()} line: {error}"
            for (kind, index), error in self.line_errors.items()
            if kind in ("step", "dir")
        }


@dataclass
class MockHardware(Hardware):
    """Hardware whose parts are simulated by ``world``. The simulated axes' positions live
    and die with the daemon's state file (key ``mock``), as the machine they stand for
    would keep its place across a restart of the daemon."""

    world: MockWorld | None = None

    def persistent_state(self) -> dict[str, Any]:
        return {} if self.world is None else {"mock": self.world.snapshot()}

    def restore_persistent_state(self, saved: dict[str, Any]) -> None:
        mock = saved.get("mock")
        if self.world is not None and isinstance(mock, dict):
            self.world.restore(mock)

    def open_alert_lines(self, uses: Sequence[tuple[str, str]]) -> EdgeInputs:
        nodes = None if self.world is None else self.world.spi_nodes  # its chips drive them
        return nodes.alert_lines(uses, self.clock) if nodes else super().open_alert_lines(uses)


def read_timeline(path: str) -> Timeline:
    """A timeline written by a step executor's own process (``timeline_file``)."""
    timeline = Timeline(None)
    with open(path, encoding="utf-8") as f:
        for line in f:
            t, kind, index, value = json.loads(line)
            timeline.record(t, EventKind(kind), index, value)
    return timeline


def mock_axis(
    endstop_min: int = ENDSTOP_MIN,
    endstop_max: int = ENDSTOP_MAX,
    switches: bool = default_of(MockAxisConfig, "switches"),
    **axis: Any,
) -> AxisSpec:
    """An axis for the mock built by hand (tests, benchmarks): ``axis`` as AxisSpec takes
    it, the simulated end stops where its ``[motors.mock]`` table would put them."""
    ends = MockAxisConfig(endstop_min=endstop_min, endstop_max=endstop_max, switches=switches)
    sections = {**axis.pop("sections", {}), MockAxisConfig: ends}
    return AxisSpec(**axis, sections=sections)


def world_of(hw: Hardware) -> MockWorld:
    """The simulated world behind mock hardware (for tests and the daemon's persistence)."""
    if not isinstance(hw, MockHardware) or hw.world is None:
        raise TypeError("not mock hardware")
    return hw.world
