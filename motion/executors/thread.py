"""The ``thread`` step executor: the step core in a thread of the daemon, or on a virtual clock.

:class:`ThreadStepExecutor` is a :class:`~motorctl.motion.executors.planner.StepExecutor` (the
planner half, which cuts the plans into step segments) whose step core
(:class:`~motorctl.motion.executors.step_core.StepCore`) runs in a thread of this process,
``motorctl-steps`` (``[step_thread] executor = "thread"``: single-core boards), at the
real-time priority the config gives it; the planner hands it segments and stops through
the core's inbox deques (:class:`~motorctl.motion.executors.core_cells.CoreInbox`). On a
virtual clock (tests, bench/steps.py) there is
no thread at all: the engine's caller drives the core through ``next_deadline`` and
``advance``.

Threads: the core and the STEP/DIR and end-stop lines it opens belong to the
``motorctl-steps`` thread (on a virtual clock: the engine's caller); what the planner
shares with it, see :class:`ThreadStepExecutor`.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Sequence

from motorctl.hal.interfaces import Hardware
from motorctl.hal.registry import open_step_io
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.executors.base import (
    AxisLimits,
    ExecEvent,
    ExecEventKind,
    ExecutorHealth,
    from_ticks,
    to_ticks,
)
from motorctl.motion.executors.core_cells import COUNTER_NAMES, CoreInbox
from motorctl.motion.executors.planner import AHEAD_S, LEAD_S, StepExecutor
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.executors.step_core import SPIN_S, StepCore
from motorctl.motion.latency import CELLS, LATE_THRESHOLD_S, LatencyStats
from motorctl.motion.rt import RealtimeOptions, RealtimeReport, enter_realtime

log = logging.getLogger("motorctl.executor")

K = ExecEventKind


class ThreadStepExecutor(StepExecutor):
    """The step core in a thread of this process (kind ``thread``), or driven by the
    engine on a virtual clock.

    Owner of the core: its thread (or the engine's caller on a virtual clock). Shared with
    the planner: only the inbox deques and the ``positions``/``levels``/``counters`` lists,
    which the GIL keeps whole.
    """

    def __init__(
        self,
        hw: Hardware,
        backend: str,
        spec: HardwareSpec,
        limits: Sequence[AxisLimits],
        *,
        ahead_s: float | None = None,
        lead_s: float | None = None,
        max_error_s: float = 5e-6,
        spin_s: float = SPIN_S,
        late_threshold_s: float = LATE_THRESHOLD_S,
        rt: RealtimeOptions | None = None,
    ) -> None:
        virtual = hw.clock.is_virtual
        super().__init__(
            hw.clock,
            limits,
            ahead_s=(0.0 if virtual else AHEAD_S) if ahead_s is None else ahead_s,
            lead_s=(0.0 if virtual else LEAD_S) if lead_s is None else lead_s,
            max_error_s=max_error_s,
        )
        self.io = open_step_io(backend, spec, hw.clock, parent=hw)
        self.rt = rt or RealtimeOptions(priority=0, lock_memory=False)
        n = len(limits)
        self.positions = [0] * n
        self.levels = [0] * len(self.io.inputs.names)
        self.counters = [0] * len(COUNTER_NAMES)
        self.stats = LatencyStats(late_threshold_s, [0] * CELLS)
        self._events: deque[ExecEvent] = deque()
        #: what the planner hands the core: deques, one producer and one consumer each
        self.inbox = CoreInbox(n)
        self.core = StepCore(
            self.io,
            limits,
            self.inbox,
            self._emit,
            positions=self.positions,
            levels=self.levels,
            counters=self.counters,
            stats=self.stats,
            motor_cells=self.motor_cells,
            spin_s=spin_s,
            coalesce_s=0.0 if virtual else max_error_s,  # virtual: the exact planned ticks
        )
        self._wake = threading.Event()
        self._running = False
        self._thread: threading.Thread | None = None
        self.died: str | None = None
        #: what real time the step thread got (None until it runs)
        self.realtime_report: RealtimeReport | None = None

    @property
    def virtual(self) -> bool:
        return self.clock.is_virtual

    def _emit(self, ev: ExecEvent) -> None:
        self._events.append(ev)
        self.on_event()

    def _raw_events(self) -> list[ExecEvent]:
        out = []
        events = self._events
        while events:
            out.append(events.popleft())
        return out

    def events_waiting(self) -> bool:
        """The core's deque holds an event (its thread appends; a deque's append is atomic,
        its death's DIED included)."""
        return bool(self._events)

    # -- the transport: the core's inbox deques ------------------------------------------
    def _push(self, motor: int, segments: list[StepSegment]) -> None:
        self.inbox.queues[motor].extend(segments)
        self._kick()

    def _push_stop(self, motor: int, gen: int, cut: int = -1) -> None:
        self.inbox.stops.append((motor, gen, cut))
        self._kick()

    def _kick(self) -> None:
        """Wake the core's thread: new work."""
        if not self.virtual:
            self._wake.set()

    def _sync(self) -> bool:
        if self.virtual:
            self.core.refill()
            return True
        return False

    # -- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        if self.virtual or self._thread is not None:
            return
        self._running = True
        started = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(started,), name="motorctl-steps", daemon=True
        )
        self._thread.start()
        started.wait()

    def _run(self, started: threading.Event) -> None:
        self.realtime_report = enter_realtime(self.rt, "the step thread")
        started.set()
        wake = self._wake

        def wait(timeout: float) -> None:
            if wake.wait(timeout):
                wake.clear()

        try:
            self.core.run(lambda: self._running, wait)
        except BaseException as exc:  # the contract: a fault, never a silent dead thread
            self.died = f"step thread died: {type(exc).__name__}: {exc}"
            log.exception("%s", self.died)
            self._emit(ExecEvent(K.DIED, -1, -1, 0, self.clock.now(), detail=self.died))

    def close(self) -> None:
        self._running = False
        self._wake.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.core.halt_all()
        self.io.close()

    # -- snapshots -----------------------------------------------------------------------
    def position(self, motor: int) -> int:
        return self.positions[motor]

    def endstop_active(self, motor: int, direction: int) -> bool:
        if self.virtual:
            self.core.refill()
        line = self.io.endstops[motor][1 if direction > 0 else 0]
        return line is not None and bool(self.levels[line])

    def health(self) -> ExecutorHealth:
        alive = self.virtual or (self._thread is not None and self._thread.is_alive())
        return ExecutorHealth(
            alive=alive and self.died is None,
            progress=self.counters[0],
            reason=self.died,
            counters=dict(zip(COUNTER_NAMES, self.counters, strict=True)),
            latency=self.stats.summary(),
        )

    def step_lateness(self) -> LatencyStats:
        return self.stats

    def step_core(self) -> str:
        return "python"  # a thread of the daemon keeps the Python core

    def realtime(self) -> RealtimeReport | None:
        return self.realtime_report

    # -- the virtual clock ---------------------------------------------------------------
    def next_deadline(self) -> float | None:
        if not self.virtual:
            return super().next_deadline()
        self.core.refill()
        d = self.core.deadline()
        return None if d is None else from_ticks(d)

    def advance(self, now: float) -> None:
        if not self.virtual:
            super().advance(now)
            return
        self.core.advance(to_ticks(now))
