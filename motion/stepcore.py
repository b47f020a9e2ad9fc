"""The step core: timed STEP/DIR edges from queued step segments, failing safe.

Owner: exactly one thread, the executor's (a thread of the daemon for the ``thread`` kind,
the main thread of the executor process for ``process``). Nothing else touches its state;
the planner talks to it only through :class:`CoreInbox` (lock-free deques, or the
shared-memory rings of ``motion.procexec``) and it answers through ``emit`` and the
``positions`` and ``counters`` cells. It may block only in ``wait`` (nothing due) and spins
only for the last ``spin_s`` before an edge.

Per step: pick the motors due now, drop any whose step would be later than
``max_lateness`` (stop, TIMING_LOST), never step sooner than ``min_interval`` after the
previous step nor before DIR has settled, raise the STEP lines of every due motor in one
call, account, then look at the end stop ahead of each motor that stepped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence

from motorctl.hal.interfaces import HalError, StepIO
from motorctl.motion.executor import (
    TICKS_PER_S,
    AxisLimits,
    ExecEvent,
    ExecEventKind,
    from_ticks,
    to_ticks,
)
from motorctl.motion.latency import Cells, LatencyStats
from motorctl.motion.segments import StepSegment

# counters cells
PROGRESS, STEPS, TIMING_LOST, IO_ERRORS, ENDSTOPS, DROPPED, MIN_GAP = range(7)
COUNTER_NAMES = ("progress", "steps", "timing_lost", "io_errors", "endstops", "dropped",
                 "min_gap_ns")
#: the smallest time between two steps of a motor (MIN_GAP) counts steps less than this apart
_GAP_WINDOW = TICKS_PER_S // 10

K = ExecEventKind
#: stopped_gen after the core stopped a motor itself: every segment is dropped until the
#: planner answers the event with a stop of a new generation
BLOCKED = 1 << 62


class CoreInbox:
    """What the planner hands the core: per-motor segment queues and hard stops."""

    def __init__(self, motors: int) -> None:
        self.queues: list[deque[StepSegment]] = [deque() for _ in range(motors)]
        self.stops: deque[tuple[int, int]] = deque()

    def pull(self) -> None:
        """Move pending work from the transport into the deques (in-process: nothing)."""


class StepCore:
    def __init__(
        self,
        io: StepIO,
        limits: Sequence[AxisLimits],
        inbox: CoreInbox,
        emit: Callable[[ExecEvent], None],
        *,
        positions: Cells,
        levels: Cells,
        counters: Cells,
        stats: LatencyStats,
        spin_s: float = 200e-6,
    ) -> None:
        n = len(limits)
        if io.outputs.motors != n:
            raise ValueError(f"{n} motors configured, the step IO drives {io.outputs.motors}")
        self.io = io
        self.clock = io.clock
        self.inbox = inbox
        self.emit = emit
        self.pos = positions
        self.levels = levels  # per input line: 0/1, published for endstop_active
        self.counters = counters
        self.stats = stats
        self.spin = to_ticks(spin_s)
        self.min_iv = [to_ticks(lim.min_interval_s) for lim in limits]
        self.max_late = [to_ticks(lim.max_lateness_s) for lim in limits]
        self.width = [lim.pulse_s for lim in limits]
        self.debounce = [to_ticks(lim.debounce_s) for lim in limits]
        # the segment being executed, per motor
        self.next_t: list[int | None] = [None] * n
        self.iv = [0] * n
        self.add = [0] * n
        self.left = [0] * n
        self.dir = [0] * n
        self.gen = [-1] * n
        self.last = [False] * n
        self.watch = [True] * n
        self.prev_t = [0] * n  # planned time of the last step emitted
        self.last_edge = [-(1 << 62)] * n  # actual time of the last step emitted
        self.stopped_gen = [-1] * n  # segments of this generation and older are dropped
        self.ready = [-(1 << 62)] * n  # DIR settled (ticks)
        inputs = io.inputs
        self.since = [0] * len(inputs.names)
        for line in range(len(inputs.names)):
            self.levels[line] = int(inputs.level(line))
        # (min line, max line) per motor, indexed by direction > 0
        self.ends = [(lo, hi) for lo, hi in io.endstops]

    # -- the planner's requests ---------------------------------------------------
    def _apply_stops(self) -> None:
        """A stop(gen) drops ``gen`` and older and lifts a block (the planner's answer)."""
        stops = self.inbox.stops
        while stops:
            m, gen = stops.popleft()
            self.stopped_gen[m] = gen
            self._drop(m)
            self.emit(ExecEvent(K.STOPPED, m, gen, self.pos[m], self._now_s()))

    def _halt(self, m: int) -> None:
        """Stop on the core's own account: drop everything until the planner answers."""
        self.stopped_gen[m] = BLOCKED
        self._drop(m)

    def _drop(self, m: int) -> None:
        if self.next_t[m] is not None and self.gen[m] <= self.stopped_gen[m]:
            self.next_t[m] = None
            self.left[m] = 0
        q = self.inbox.queues[m]
        while q and q[0].gen <= self.stopped_gen[m]:
            q.popleft()
            self.counters[DROPPED] += 1

    def _load(self, m: int) -> bool:
        """Take the motor's next segment; True when one is loaded."""
        q = self.inbox.queues[m]
        while q:
            if self.stopped_gen[m] == BLOCKED and self.inbox.stops:
                self._apply_stops()  # the answer may have come with these segments
            seg = q.popleft()
            if seg.gen <= self.stopped_gen[m]:
                self.counters[DROPPED] += 1
                continue
            self.next_t[m] = seg.first
            self.iv[m] = seg.interval
            self.add[m] = seg.add
            self.left[m] = seg.count
            self.gen[m] = seg.gen
            self.last[m] = seg.last
            self.watch[m] = seg.watch
            if seg.direction != self.dir[m]:
                self._set_dir(m, seg.direction)
            return True
        return False

    def _set_dir(self, m: int, d: int) -> None:
        outputs = self.io.outputs
        try:
            outputs.set_direction(m, d > 0)
        except HalError as exc:
            self._io_fault((m,), exc)
            return
        self.dir[m] = d
        self.ready[m] = to_ticks(outputs.ready_at[m])

    def refill(self) -> None:
        self.inbox.pull()
        if self.inbox.stops:
            self._apply_stops()
        self._edges()
        next_t = self.next_t
        for m in range(len(next_t)):
            if next_t[m] is None and self.inbox.queues[m]:
                self._load(m)

    # -- time ------------------------------------------------------------------------
    def _now_s(self) -> float:
        return self.clock.now()

    def due(self, m: int) -> int | None:
        """When motor m's next step may be emitted (planned, spacing and DIR settled)."""
        t = self.next_t[m]
        if t is None:
            return None
        earliest = self.last_edge[m] + self.min_iv[m]
        if earliest > t:
            t = earliest
        return t if t >= self.ready[m] else self.ready[m]

    def deadline(self) -> int | None:
        best: int | None = None
        for m in range(len(self.next_t)):
            d = self.due(m)
            if d is not None and (best is None or d < best):
                best = d
        return best

    # -- one edge ----------------------------------------------------------------------
    def step(self, now: int) -> None:
        """Emit every step due at ``now`` (ticks)."""
        due: list[int] = []
        for m in range(len(self.next_t)):
            d = self.due(m)
            if d is None or d > now:
                continue
            planned = self.next_t[m]
            assert planned is not None
            if now - planned > self.max_late[m]:
                self._timing_lost(m, now, planned)
                continue
            due.append(m)
        if not due:
            return
        width = max(self.width[m] for m in due)
        try:
            rise = to_ticks(self.io.outputs.pulse(due, width))
        except HalError as exc:
            self._io_fault(due, exc)
            return
        stats, pos, counters = self.stats, self.pos, self.counters
        for m in due:
            planned = self.next_t[m]
            assert planned is not None
            stats.record_ns(rise - planned)
            gap = rise - self.last_edge[m]
            if gap < _GAP_WINDOW and (gap < counters[MIN_GAP] or not counters[MIN_GAP]):
                counters[MIN_GAP] = gap
            pos[m] += self.dir[m]
            counters[STEPS] += 1
            self.prev_t[m] = planned
            self.last_edge[m] = rise
            left = self.left[m] - 1
            self.left[m] = left
            if left > 0:
                self.next_t[m] = planned + self.iv[m]
                self.iv[m] += self.add[m]
            else:
                was_last = self.last[m]
                self.next_t[m] = None
                if not self._load(m) and was_last:
                    self.emit(ExecEvent(K.DONE, m, self.gen[m], pos[m], from_ticks(rise)))
        self._edges()
        now = to_ticks(self.clock.now())
        for m in due:
            self._check_endstop(m, now)

    def _edges(self) -> None:
        try:
            edges = self.io.inputs.read_edges()
        except HalError as exc:
            self._io_fault(tuple(range(len(self.next_t))), exc)
            return
        for e in edges:
            self.levels[e.line] = int(e.active)
            if e.active:
                self.since[e.line] = to_ticks(e.t)

    def _check_endstop(self, m: int, now: int) -> None:
        if not self.watch[m]:
            return
        d = self.dir[m]
        line = self.ends[m][1 if d > 0 else 0]
        if line is None or not self.levels[line]:
            return
        since = self.since[line]
        if now - since < self.debounce[m]:
            return
        gen = self.gen[m]
        self._halt(m)
        self.counters[ENDSTOPS] += 1
        self.emit(ExecEvent(K.ENDSTOP, m, gen, self.pos[m], from_ticks(max(since, 0)), d))

    def _speed(self, m: int, planned: int) -> float:
        gap = planned - self.prev_t[m]
        return TICKS_PER_S / gap if 0 < gap < TICKS_PER_S else 0.0

    def _timing_lost(self, m: int, now: int, planned: int) -> None:
        gen = self.gen[m]
        speed = self._speed(m, planned)
        self._halt(m)
        self.counters[TIMING_LOST] += 1
        late_us = (now - planned) / 1000
        self.emit(ExecEvent(K.TIMING_LOST, m, gen, self.pos[m], from_ticks(now), self.dir[m],
                            speed, f"step {late_us:.0f} us late"))

    def _io_fault(self, motors: Sequence[int], exc: Exception) -> None:
        self.counters[IO_ERRORS] += 1
        for m in motors:
            gen = self.gen[m]
            t = self.next_t[m]
            speed = 0.0 if t is None else self._speed(m, t)
            self._halt(m)
            self.emit(ExecEvent(K.FAULT, m, gen, self.pos[m], self._now_s(), self.dir[m],
                                speed, f"hardware error: {exc}"))

    def halt_all(self) -> None:
        for m in range(len(self.next_t)):
            self._halt(m)

    # -- drivers ---------------------------------------------------------------------
    def advance(self, now: int) -> None:
        """Virtual clock: do everything due up to ``now`` (the caller moves the clock)."""
        self.refill()
        self.step(now)
        self.refill()

    def run(self, running: Callable[[], bool], wait: Callable[[float], None],
            idle_s: float = 0.05) -> None:
        """Real clock: the loop, until ``running()`` is False."""
        clock = self.clock
        counters = self.counters
        stops = self.inbox.stops
        spin = self.spin
        while running():
            counters[PROGRESS] += 1
            self.refill()
            d = self.deadline()
            if d is None:
                wait(idle_s)
                continue
            now = to_ticks(clock.now())
            if d - now > spin:
                wait(min((d - spin - now) / TICKS_PER_S, idle_s))
                continue
            target = d / TICKS_PER_S
            t = clock.now()
            while t < target and not stops:
                t = clock.now()
            if stops:
                continue
            self.step(to_ticks(t))
