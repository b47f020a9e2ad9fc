"""The compiled step core: loading the extension and driving it over the shared block.

``motorctl.motion.executors._stepcore`` (built from ``motion/executors/csrc/`` by the
project's build, never at run time: setup.py) is ``motion/executors/step_core.py`` in C,
with the same contract: step segments in from the process executor's shared-memory rings
(each record checked by its CRC-32 and its fields), edges on the lines, and out the same
events, positions, levels, counters, per-motor figures and lateness histogram in the same
cells. Its lines come from the backend's StepIO as the capability "lines a compiled core may
drive" (:data:`~motorctl.hal.interfaces.CompiledLines`): GPIO character-device requests,
written and read with ioctls, or the mock's simulated mechanics, whose compiled counterpart
records the same timeline of edges with times as the Python mock.

Two ways to drive it:

- :meth:`CompiledStepCore.run`: the executor process's whole loop, with the GIL released,
  until the daemon clears the run cell (or is gone); Python runs again only to stop it;
- a virtual clock (tests, ``bench/steps.py``'s cost): :meth:`~CompiledStepCore.refill`,
  :meth:`~CompiledStepCore.deadline`, :meth:`~CompiledStepCore.advance` and
  :meth:`~CompiledStepCore.run_until` as the Python core's, the clock moved by the caller
  (and by a DIR settle time the core waits out), events handed to ``emit`` and the
  simulated edges to the mock's timeline after each call.

``MOTORCTL_STEPCORE``: the path of another build of the extension to load instead (``make
test-asan`` runs the tests on one built with the address and undefined-behaviour
sanitizers); unset in production.

Owner: the thread that made the core (the executor process's main thread, or a test's).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

from motorctl.hal.compiled_lines import ChardevLines, SimulatedLines
from motorctl.hal.interfaces import StepIO, VirtualClock
from motorctl.motion.executors.base import TICKS_PER_S, AxisLimits, ExecEvent, to_ticks
from motorctl.motion.executors.core_cells import COUNTER_NAMES, MOTOR_CELLS
from motorctl.motion.executors.process.rings import (
    BAD_RECORD_S,
    EVENT_RECORD,
    EVENT_RING,
    SEG_RECORD,
    SEG_RING,
    STOP_RECORD,
    STOP_RING,
    Shared,
    decode_event,
)
from motorctl.motion.executors.step_core import SPIN_S
from motorctl.motion.latency import CELLS, LATE_THRESHOLD_S, LatencyStats

NAME = "compiled"
ENV = "MOTORCTL_STEPCORE"
_MODULE = "motorctl.motion.executors._stepcore"


def load() -> ModuleType:
    """The extension (the build ``MOTORCTL_STEPCORE`` names, if set); ImportError when it is
    not built or does not match this code."""
    path = os.environ.get(ENV)
    if path:
        spec = importlib.util.spec_from_file_location(_MODULE, path)
        if spec is None or spec.loader is None:
            raise ImportError(f"{ENV}={path}: not a loadable extension")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    else:
        mod = importlib.import_module(_MODULE)
    want = {
        "COUNTERS": len(COUNTER_NAMES),
        "MOTOR_CELLS": MOTOR_CELLS,
        "LATENCY_CELLS": CELLS,
        "SEGMENT_RECORD": SEG_RECORD.size,
        "STOP_RECORD": STOP_RECORD.size,
        "EVENT_RECORD": EVENT_RECORD.size,
    }
    have = {k: getattr(mod, k, None) for k in want}
    if have != want:
        raise ImportError(f"{_MODULE} was built from other sources ({have}, expected {want})")
    return mod


def unavailable(io: StepIO | None = None) -> str | None:
    """Why the compiled core cannot run (over ``io``'s lines, when given); None: it can."""
    try:
        load()
    except ImportError as exc:
        return (
            f"the compiled step core is not built ({exc}); the project's build makes it "
            "(make venv, pip install, the Debian package; it needs gcc and the Python headers)"
        )
    if io is not None and io.compiled is None:
        return io.compiled_missing
    return None


class CompiledStepCore:
    """The compiled core over ``shared`` (a :class:`~motorctl.motion.executors.process.rings.Shared`
    block: its rings are the inbox, its cells the output), driving ``io``'s compiled lines
    for ``limits``' motors. ``emit`` (virtual clock) receives the events; on the real clock
    the daemon reads them from the event ring."""

    def __init__(
        self,
        io: StepIO,
        limits: Sequence[AxisLimits],
        shared: Shared,
        *,
        late_threshold_s: float = LATE_THRESHOLD_S,
        spin_s: float = SPIN_S,
        coalesce_s: float = 0.0,
        idle_s: float = 0.05,
        bad_record_s: float = BAD_RECORD_S,
        emit: Callable[[ExecEvent], None] | None = None,
    ) -> None:
        n = len(limits)
        if io.outputs.motors != n:
            raise ValueError(f"{n} motors configured, the step IO drives {io.outputs.motors}")
        lines = io.compiled
        if lines is None:
            raise ValueError(f"no lines for a compiled core: {io.compiled_missing}")
        mod = load()
        self.io = io
        self.clock = io.clock
        self.shared = shared
        self.emit = emit
        lay = shared.layout
        buf = shared.shm.buf
        assert buf is not None
        self._core: Any = mod.Core(
            buf,
            (
                lay.header,
                lay.counters,
                lay.positions,
                lay.levels,
                lay.latency,
                lay.motor_cells,
                lay.stop_ring,
                lay.event_ring,
            ),
            tuple(lay.seg_rings),
            (SEG_RING, STOP_RING, EVENT_RING),
            n,
            len(io.inputs.names),
            (
                int(late_threshold_s * 1e9),
                to_ticks(spin_s),
                to_ticks(coalesce_s),
                to_ticks(idle_s),
                to_ticks(bad_record_s),
            ),
        )
        out = io.outputs
        for m, lim in enumerate(limits):
            lo, hi = io.endstops[m]
            rule = lim.lag_rule()  # the C core's late steps mirror LagRule.loses_steps
            self._core.motor(
                m,
                to_ticks(lim.min_interval_s),
                to_ticks(lim.slide_after_s),
                rule.start_gap,
                to_ticks(lim.pulse_s),
                to_ticks(lim.debounce_s),
                rule.microsteps,
                rule.lag_k,
                rule.max_lag_full_steps,
                rule.start_speed,
                lim.lag_faults,
                -1 if lo is None else lo,
                -1 if hi is None else hi,
                out.invert_dir[m],
                to_ticks(out.dir_setup_s[m]),
                to_ticks(out.dir_hold_s[m]),
            )
        self._sim: SimulatedLines | None = None
        self._errors: dict[tuple[str, int], str] = {}
        self._calls: list[list[int]] | None = None
        if isinstance(lines, ChardevLines):
            self._gpio(lines)
        else:
            self._sim = lines
            self._core.sim(
                lines.cells,
                [lo for lo, _ in lines.endstops],
                [hi for _, hi in lines.endstops],
                [int(sw) for sw in lines.switches],
                list(lines.axis_of),
                -1 if lines.timeline_len is None else lines.timeline_len,
            )
            self._sync_errors()
        self.virtual = self.clock.is_virtual
        self._core.start(self.virtual, self.clock.now_ns())
        self.positions = shared.positions
        self.levels = shared.levels
        self.counters = shared.counters
        self.motor_cells = shared.motor_cells
        self.stats = LatencyStats(late_threshold_s, shared.latency)

    def _gpio(self, lines: ChardevLines) -> None:
        inputs = self.io.inputs
        for line in range(len(inputs.names)):
            self._core.level(line, inputs.level(line))
        self._core.gpio(
            [
                (r.fd, r.uapi, bytes(int(v) for v in r.levels or (False,) * len(r.offsets)))
                for r in lines.outputs
            ],
            list(lines.step),
            list(lines.dir),
            [
                (r.fd, r.uapi, list(zip(r.offsets, nums, strict=True)))
                for r, nums in zip(lines.inputs, lines.input_lines, strict=True)
            ],
            bytes(int(v) for v in lines.active_low),
        )

    # -- the simulated lines (the mock) ----------------------------------------------------
    def _sync(self) -> None:
        """Before a virtual-clock call: the caller's clock (a stall) and the mock's injected
        line errors as they are now (a test may change either)."""
        self._core.clock(self.clock.now_ns())
        self._sync_errors()

    def _sync_errors(self) -> None:
        if self._sim is None:
            return
        now = self._sim.line_errors()
        if now == self._errors:
            return
        for key in self._errors.keys() - now.keys():
            self._core.sim_error(key[0], key[1], None)
        for (kind, axis), text in now.items():
            if self._errors.get((kind, axis)) != text:
                self._core.sim_error(kind, axis, text)
        self._errors = dict(now)

    def _drain(self) -> None:
        """The simulated edges to the mock's timeline; the events to ``emit``."""
        if self._sim is not None:
            edges = self._core.timeline()
            if edges:
                self._sim.record(edges)
                if self._calls is not None:
                    motor_of = {a: m for m, a in enumerate(self._sim.axis_of)}
                    groups: dict[int, list[int]] = {}
                    for _t, kind, axis, _value, call in edges:
                        if kind == 0:
                            groups.setdefault(call, []).append(motor_of[axis])
                    self._calls.extend(groups.values())
        if self.emit is not None:
            ring = self.shared.events
            while (rec := ring.get()) is not None:
                self.emit(decode_event(rec))

    def pulse_calls(self) -> list[list[int]]:
        """From now on (simulated lines), the motors of each STEP rise, one list per call."""
        self._calls = []
        return self._calls

    # -- the virtual clock -------------------------------------------------------------------
    def _moved(self) -> None:
        clock = self.clock
        if isinstance(clock, VirtualClock):  # a DIR settle time waited out moves it on
            clock.advance_to(self._core.now() / TICKS_PER_S)
        self._drain()

    def refill(self) -> None:
        self._sync()
        self._core.refill()
        self._moved()

    def deadline(self) -> int | None:
        d: int | None = self._core.deadline()
        return d

    def advance(self, now: int) -> None:
        """Virtual clock: do everything due up to ``now`` (ticks)."""
        self._sync()
        self._core.advance(now)
        self._moved()

    def run_until(self, until: int) -> None:
        """Virtual clock: every edge up to tick ``until``, the clock moved to each."""
        self._sync()
        self._core.run_until(until)
        self._moved()

    # -- the real clock ----------------------------------------------------------------------
    def run(self, wake_fd: int, event_fd: int, parent: int) -> None:
        """The loop (the GIL released) until the block's run cell is 0 or the process
        ``parent`` is gone (0: not watched); ``wake_fd``: the daemon's wake-up pipe (read
        end), ``event_fd``: a byte there after each event."""
        self._core.run(wake_fd, event_fd, parent)

    def halt_all(self) -> None:
        self._core.halt_all()

    def close(self) -> None:
        """The last simulated edges to the timeline, then the core's memory and its hold on
        the block (before the block and the lines close)."""
        if self._sim is not None:
            edges = self._core.timeline()
            if edges:
                self._sim.record(edges)
        self._core.close()
