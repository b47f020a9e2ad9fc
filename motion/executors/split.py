"""One seam over several executors: each motor to the executor that moves it.

:class:`SplitExecutor` routes each motor to one of several executors (STEP/DIR motors to
the step executor, motors whose driver chip runs its own ramp to a
:class:`~motorctl.motion.executors.chip_ramp.RampExecutor`) behind the one seam the engine
uses, and maps their events back to the machine's motor numbers. :func:`with_ramp_motors`
builds the machine's executor from its drivers.

Threads: as every :class:`~motorctl.motion.executors.base.Executor`; it keeps no state of its
own after construction but the routes, and forwards every call to the part that owns the
motor (the snapshots too: they are the parts' own).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from motorctl.hal.interfaces import Clock, RampDriver
from motorctl.motion.executors.base import (
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
    ExecutorHealth,
)
from motorctl.motion.executors.chip_ramp import RampExecutor
from motorctl.motion.latency import LatencyStats
from motorctl.motion.profile import Trajectory
from motorctl.motion.rt import RealtimeReport
from motorctl.motion.types import Ramp

K = ExecEventKind


#: counters that hold the smallest value seen, not a count (0 while none was seen)
_SMALLEST = frozenset({"min_gap_ns"})


class SplitExecutor(Executor):
    """Each motor to one of several executors, behind the one seam the engine uses.

    ``routes[m] = (executor, local)``: motor ``m`` is the executor's motor ``local``. An
    executor may drive motors that are not routed to it (a step executor built for every
    axis, whose TMC5160 ramp axes go to a RampExecutor): they are never given work. A part
    that dies is the executor dying (DIED, motor -1): every motor faults, position lost,
    and the daemon exits for its service manager to restart it, as with one executor.
    """

    def __init__(self, routes: Sequence[tuple[Executor, int]]) -> None:
        super().__init__(len(routes))
        self.routes = list(routes)
        self.parts: list[Executor] = []
        seen: set[tuple[int, int]] = set()
        for m, (ex, local) in enumerate(self.routes):
            if not 0 <= local < ex.motors:
                raise ValueError(f"motor {m}: {type(ex).__name__} has no motor {local}")
            if (id(ex), local) in seen:
                raise ValueError(f"motor {m}: {type(ex).__name__}'s motor {local} is taken")
            seen.add((id(ex), local))
            if all(p is not ex for p in self.parts):
                self.parts.append(ex)
        self._back = {(id(ex), local): m for m, (ex, local) in enumerate(self.routes)}
        for ex in self.parts:
            ex.on_event = self._forward

    def _forward(self) -> None:
        self.on_event()

    def start(self) -> None:
        for ex in self.parts:
            ex.start()

    def close(self) -> None:
        for ex in self.parts:
            ex.close()

    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        ex, local = self.routes[motor]
        return ex.follow(local, traj, ramp, gen, endstops, release)

    def stop(self, motor: int, gen: int) -> int | None:
        ex, local = self.routes[motor]
        return ex.stop(local, gen)

    def committed(self, motor: int, now: float) -> Committed:
        ex, local = self.routes[motor]
        return ex.committed(local, now)

    def planned(self, motor: int) -> bool:
        ex, local = self.routes[motor]
        return ex.planned(local)

    def service(self, now: float) -> float:
        return min(ex.service(now) for ex in self.parts)

    def events(self) -> list[ExecEvent]:
        out: list[ExecEvent] = []
        for ex in self.parts:
            for ev in ex.events():
                if ev.kind is K.DIED:  # the executor's death, as without ramp motors:
                    out.append(ev)  # every motor faults, position lost; the daemon exits 3
                    continue
                m = self._back.get((id(ex), ev.motor))
                if m is not None:  # events of unrouted motors concern nobody
                    out.append(replace(ev, motor=m))
        return out

    def events_waiting(self) -> bool:
        return any(ex.events_waiting() for ex in self.parts)

    def position(self, motor: int) -> int:
        ex, local = self.routes[motor]
        return ex.position(local)

    def endstop_active(self, motor: int, direction: int) -> bool:
        ex, local = self.routes[motor]
        return ex.endstop_active(local, direction)

    def health(self) -> ExecutorHealth:
        parts = [ex.health() for ex in self.parts]
        counters: dict[str, int] = {}
        for h in parts:
            for k, v in h.counters.items():
                if k in _SMALLEST:  # the smallest that any part saw (0: none seen)
                    seen = counters.get(k, 0)
                    counters[k] = v if v and (not seen or v < seen) else seen
                else:
                    counters[k] = counters.get(k, 0) + v
        return ExecutorHealth(
            alive=all(h.alive for h in parts),
            progress=sum(h.progress for h in parts),
            reason=next((h.reason for h in parts if h.reason), None),
            counters=counters,
            latency=next((h.latency for h in parts if h.latency), {}),
        )

    @property
    def pid(self) -> int | None:
        """The process of the part that runs in one (a ``process`` step executor), if any."""
        return next(
            (p for ex in self.parts if isinstance(p := getattr(ex, "pid", None), int)), None
        )

    def motor_time(self, motor: int, now: float) -> float:
        ex, local = self.routes[motor]
        return ex.motor_time(local, now)

    def motor_timing(self, motor: int) -> dict[str, Any]:
        ex, local = self.routes[motor]
        return ex.motor_timing(local)

    @property
    def times_steps(self) -> bool:
        """True when a part does (the step executor; the ramp executor makes no STEP edges)."""
        return any(ex.times_steps for ex in self.parts)

    def step_lateness(self) -> LatencyStats | None:
        """The step executor's (the ramp executor makes no STEP edges)."""
        return next((s for ex in self.parts if (s := ex.step_lateness()) is not None), None)

    def step_core(self) -> str | None:
        """The step executor's (the ramp executor has none)."""
        return next((c for ex in self.parts if (c := ex.step_core()) is not None), None)

    def realtime(self) -> RealtimeReport | None:
        """The step executor's (the ramp executor has no real-time part)."""
        return next((r for ex in self.parts if (r := ex.realtime()) is not None), None)

    def next_deadline(self) -> float | None:
        found = [d for ex in self.parts if (d := ex.next_deadline()) is not None]
        return min(found) if found else None

    def advance(self, now: float) -> None:
        for ex in self.parts:
            ex.advance(now)


def with_ramp_motors(
    executor: Executor | None,
    drivers: Sequence[object],
    clock: Clock,
    poll_s: float | None = None,
    idle_poll_s: float | None = None,
) -> Executor:
    """The machine's executor: ``executor`` (the step executor) for the motors whose driver
    does not run its own ramp (is no :class:`RampDriver`), numbered among themselves in order
    as ``HardwareSpec.stepped()`` numbers them; the ramp motors go to one
    :class:`RampExecutor`, polled as often as the most eager of them asks (``poll_s``,
    ``idle_poll_s`` given: those). ``executor`` unchanged when there are no ramp motors; None
    when every motor is one."""
    ramp = [i for i, d in enumerate(drivers) if isinstance(d, RampDriver)]
    stepped = [i for i, d in enumerate(drivers) if not isinstance(d, RampDriver)]
    if stepped and executor is None:
        raise ValueError(f"motors {stepped} need a step executor")
    if not ramp:
        assert executor is not None
        return executor
    chips = [d for d in drivers if isinstance(d, RampDriver)]
    poll = min(c.poll_s for c in chips) if poll_s is None else poll_s
    idle = min(c.idle_poll_s for c in chips) if idle_poll_s is None else idle_poll_s
    ramp_ex = RampExecutor(chips, clock, poll, idle)
    if not stepped:
        return ramp_ex
    assert executor is not None
    routes: list[tuple[Executor, int]] = []
    for m in range(len(drivers)):
        routes.append((ramp_ex, ramp.index(m)) if m in ramp else (executor, stepped.index(m)))
    return SplitExecutor(routes)
