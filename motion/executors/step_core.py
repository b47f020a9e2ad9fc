"""The step core: timed STEP/DIR edges from queued step segments, failing safe.

THE HOT LOOP. This module is to motorctl what Klipper's C helper is to Klippy: the one
place that runs per step, in real time, and it keeps rules of its own. Read them before
changing anything here, and keep to them in what it calls:

- One owner. Exactly one thread runs it: a thread of the daemon for the ``thread`` kind
  (``thread.py``), the main thread of the executor's own process for ``process``
  (``process/child.py``), or the engine's caller on a virtual clock. Nothing else
  touches its state.
- No locks. The planner reaches it only through :class:`CoreInbox` (deques that the GIL
  makes safe for one producer and one consumer, or the shared-memory rings of
  ``process/rings.py``); it answers through ``emit`` and cells (``positions``,
  ``levels``, ``counters``, ``motor_cells``, the latency histogram): one store per
  value, read by others as snapshots. ``emit`` must be cheap and never block (a deque
  append, a ring record and a wake-up byte).
- No allocation per step. Per-motor state lives in lists made at start, indexed by
  motor; the motors due and done at an edge go into the core's own two lists, cleared
  and refilled. New objects are made only for what ends or stops a motion (an
  :class:`~motorctl.motion.executors.base.ExecEvent`), never per step; the ints of the
  tick arithmetic are CPython's own. The executor's process runs with the garbage
  collector off, the daemon while anything moves (``rt.GcPolicy``): garbage made here
  would pile up, or cost a collection pause in the thread kind.
- No logging, no printing, no I/O but the HAL's. The only calls out are the StepIO's
  (``StepOutputs.set_direction``/``rise``/``fall``, ``EdgeInputs.read_edges``/``level``):
  one backend call each, which may not block. A backend raises only ``HalError`` at run
  time; the core catches it at each call and makes it a FAULT event of the motors
  concerned: the loop never dies of a hardware error.
- What may block: only ``wait`` (the caller's, when nothing is due within ``spin_s``);
  the core spins only for the last ``spin_s`` before an edge and for the STEP pulse
  width (``StepOutputs.fall``). Nothing here sleeps, joins or waits for the planner.
- Its cost is measured: ``bench/steps.py`` prints ``core_cost_us_python`` (and its twin's
  ``core_cost_us_compiled``), the CPU time per step on mock lines. A change here quotes it
  before and after and must not make it worse.
- A twin: the compiled core (``csrc/core.c``, driven by ``compiled_core.py``) keeps every
  rule here in C, function by function; the executor process runs it where it is built. A
  change to a rule is made in both, and the core's tests run on both
  (tests/motion/executors/test_step_core.py). This one stays the readable reference and
  the fallback.
- One module on purpose (but its inbox and published cells: ``core_cells.py``): the loop's
  state and every path that touches it are read together.

Per step: pick the motors due now; a motor whose step comes later than ``slide_after`` has
the rest of its schedule slid by that lateness (its ``shift``: the planner reads it and
plans on the motor's own slid time), unless the lag it caused, in full steps, is one a real
motor may not survive (:class:`~motorctl.motion.executors.base.AxisLimits`): then it stops
(TIMING_LOST). Never step sooner than ``min_interval`` after the previous step nor before
DIR has settled, raise the STEP lines of every due motor in one call, account while they are
high, lower them, then look at the end stop ahead of each motor that stepped (and, in a plan
that watches for it, whether the end stop behind has released: homing's back-off stops
there, RELEASED); and before a segment's first (already active: no step). Each motor's
next due time is kept up to date as its state changes, so finding the next edge is one
``min`` over the motors. Times are integer ns (ticks); a segment's ticks are plan ticks,
made at plan tick + the motor's shift. A motor whose step is planned within ``coalesce_s``
after the edge being made (and that nothing else holds back) shares its pulse: up to
``coalesce_s`` early, within the planner's own step error bound, instead of queueing a few
microseconds behind it.

Stops from the planner: ``(motor, gen, -1)`` drops every segment of ``gen`` and older and
reports STOPPED (a hard stop); ``(motor, gen, cut)`` drops only those of ``gen`` and older
that start at or after tick ``cut``, silently: a re-plan takes over there. A segment of
``count`` 0 is a marker: the plan before it is complete (DONE when it is ``last``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

from motorctl.hal.interfaces import HalError, StepIO
from motorctl.motion.executors.base import (
    ENDSTOP_ALREADY_ACTIVE,
    TICKS_PER_S,
    AxisLimits,
    ExecEvent,
    ExecEventKind,
    from_ticks,
    to_ticks,
)
from motorctl.motion.executors.core_cells import (
    ABSORBED,
    BAD_RECORDS,
    DISCARDED,
    ENDSTOPS,
    IO_ERRORS,
    LAG_FAULTS,
    LAG_UNIT,
    MIN_GAP,
    MOTOR_CELLS,
    PROGRESS,
    SHIFT,
    STEPS,
    TIMING_LOST,
    WORST_LAG,
    WORST_LATE,
    CoreInbox,
)
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.latency import Cells, LatencyStats

#: the core sleeps until this long before its next edge and spins the rest ([step_thread]
#: spin_us declares it with this value)
SPIN_S: Final = 200e-6

#: the smallest time between two steps of a motor (MIN_GAP) counts steps less than this apart
_GAP_WINDOW = TICKS_PER_S // 10

K = ExecEventKind
#: stopped_gen after the core stopped a motor itself: every segment is dropped until the
#: planner answers the event with a stop of a new generation
BLOCKED = 1 << 62
#: no step pending
NEVER = 1 << 62
#: the largest value of a shared int64 cell
_CELL_MAX = (1 << 63) - 1


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
        motor_cells: Cells | None = None,
        spin_s: float = SPIN_S,
        coalesce_s: float = 0.0,
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
        self.coalesce = to_ticks(coalesce_s)
        self.motors = range(n)
        self.min_iv = [to_ticks(lim.min_interval_s) for lim in limits]
        self.slide_after = [to_ticks(lim.slide_after_s) for lim in limits]
        # how a late step is judged: the one lag rule (motion/executors/base.py)
        self.lag_rule = [lim.lag_rule() for lim in limits]
        self.lag_faults = [lim.lag_faults for lim in limits]
        self.mcells: Cells = motor_cells if motor_cells is not None else [0] * (n * MOTOR_CELLS)
        if len(self.mcells) < n * MOTOR_CELLS:
            raise ValueError(f"motor cells need {n * MOTOR_CELLS} slots")
        # the lateness of a step that slid its motor's schedule, until the step is made
        self.slid = [0] * n
        self.width = [to_ticks(lim.pulse_s) for lim in limits]
        self.debounce = [to_ticks(lim.debounce_s) for lim in limits]
        # the segment being executed, per motor
        self.next_t = [NEVER] * n  # planned time of the next step
        self.due_t = [NEVER] * n  # when it may be made: planned, spacing, DIR settled
        self.iv = [0] * n
        self.add = [0] * n
        self.left = [0] * n
        self.dir = [0] * n
        self.gen = [-1] * n
        self.last = [False] * n
        self.watch = [True] * n
        self.release = [False] * n  # stop where the end stop behind releases
        # where it was seen released (NEVER: not seen) and the edge it was seen by
        self.rel_at = [NEVER] * n
        self.rel_since = [0] * n
        self.seg_first = [0] * n
        self.seg_count = [0] * n
        self.prev_t = [0] * n  # planned time of the last step emitted
        self.last_edge = [-(1 << 62)] * n  # actual time of the last step emitted
        self.stopped_gen = [-1] * n  # segments of this generation and older are dropped
        # re-plans: (gen, tick) per cut, segments of gen or older from tick on are dropped;
        # every cut still pending counts (a segment of an older plan may still be on its way
        # when the next re-plan cuts the newer one later)
        self.cuts: list[list[tuple[int, int]]] = [[] for _ in range(n)]
        self.ready = [-(1 << 62)] * n  # DIR settled (ticks)
        inputs = io.inputs
        self.since = [0] * len(inputs.names)
        for line in range(len(inputs.names)):
            self.levels[line] = int(inputs.level(line))
        # (min line, max line) per motor, indexed by direction > 0
        self.ends = [(lo, hi) for lo, hi in io.endstops]
        # the motors due at this edge and those whose segment it ended: the core's own
        # lists, cleared and refilled by each step() (nothing is allocated per step)
        self._due: list[int] = []
        self._done: list[int] = []

    # -- the planner's requests ---------------------------------------------------
    def _apply_stops(self) -> None:
        """A stop(gen) drops ``gen`` and older and lifts a block (the planner's answer)."""
        stops = self.inbox.stops
        while stops:
            m, gen, cut = stops.popleft()
            if cut >= 0:
                self._cut(m, gen, cut)
                continue
            self.stopped_gen[m] = gen
            self.cuts[m].clear()  # every cut so far was of an older plan: all dropped now
            self._drop(m)
            self.emit(ExecEvent(K.STOPPED, m, gen, self.pos[m], self._now_s()))

    def _cut(self, m: int, gen: int, cut: int) -> None:
        """A re-plan: segments of ``gen`` and older from tick ``cut`` on are not made."""
        if self.stopped_gen[m] == BLOCKED:
            return  # stopped on our own account: everything is dropped until the answer
        self.cuts[m].append((gen, cut))
        if self.next_t[m] != NEVER and self.gen[m] <= gen and self.seg_first[m] >= cut:
            if self.left[m] < self.seg_count[m]:  # it began already: the re-plan came late
                now = self.clock.now_ns()
                late = now - cut - self.mcells[m * MOTOR_CELLS + SHIFT]
                self._lost(m, now, f"re-plan came {late / 1000:.0f} us late")
                return
            self._unload(m)
        if self.next_t[m] == NEVER:
            self._load(m)  # drops what the cut removed (as it will for what comes later)

    def _cut_off(self, m: int, seg: StepSegment) -> bool:
        """A re-plan dropped this segment."""
        gen, first = seg.gen, seg.first
        return any(gen <= g and first >= t for g, t in self.cuts[m])

    def _halt(self, m: int) -> None:
        """Stop on the core's own account: drop everything until the planner answers."""
        self.stopped_gen[m] = BLOCKED
        self._drop(m)

    def _unload(self, m: int) -> None:
        self.next_t[m] = self.due_t[m] = NEVER
        self.left[m] = 0

    def _drop(self, m: int) -> None:
        if self.next_t[m] != NEVER and self.gen[m] <= self.stopped_gen[m]:
            self._unload(m)
        q = self.inbox.queues[m]
        while q and q[0].gen <= self.stopped_gen[m]:
            q.popleft()
            self.counters[DISCARDED] += 1

    def _load(self, m: int) -> bool:
        """Take the motor's next segment; True when one is loaded."""
        q = self.inbox.queues[m]
        while q:
            if self.stopped_gen[m] == BLOCKED and self.inbox.stops:
                self._apply_stops()  # the answer may have come with these segments
                if self.next_t[m] != NEVER:
                    return True  # a cut in that answer loaded it already
                continue  # (it may have dropped every queued segment)
            seg = q.popleft()
            gen = seg.gen
            cuts = self.cuts[m]
            if gen <= self.stopped_gen[m] or (cuts and self._cut_off(m, seg)):
                self.counters[DISCARDED] += 1
                continue
            if cuts and cuts[0][0] < gen:  # no segment of those plans comes any more
                cuts[:] = [c for c in cuts if c[0] >= gen]
            if seg.count <= 0:  # a marker: the plan before it is complete
                if seg.last:
                    self.emit(ExecEvent(K.DONE, m, gen, self.pos[m], self._now_s()))
                continue
            if seg.watch and self._on_end_ahead(m, gen, seg.direction):
                return False  # the end stop ahead is active already: no step toward it
            first = seg.first
            self.next_t[m] = first = first + self.mcells[m * MOTOR_CELLS + SHIFT]
            self.iv[m] = seg.interval
            self.add[m] = seg.add
            self.left[m] = self.seg_count[m] = seg.count
            self.seg_first[m] = seg.first  # plan ticks, as the planner's cuts
            if gen != self.gen[m]:
                self.rel_at[m] = NEVER  # a new plan sees the release for itself
            self.gen[m] = gen
            self.last[m] = seg.last
            self.watch[m] = seg.watch
            self.release[m] = seg.release
            if seg.direction != self.dir[m]:
                self._set_dir(m, seg.direction)
                if self.next_t[m] == NEVER:
                    return False  # the DIR write failed: faulted
            earliest = self.last_edge[m] + self.min_iv[m]
            d = first if first >= earliest else earliest
            ready = self.ready[m]
            self.due_t[m] = d if d >= ready else ready
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

    def _take(self) -> None:
        """New work: pull the transport, apply stops, load idle motors."""
        inbox = self.inbox
        inbox.pull()
        if inbox.stops:
            self._apply_stops()
        if inbox.faults:
            self._bad_records()
        next_t = self.next_t
        if NEVER in next_t:
            queues = inbox.queues
            for m in self.motors:
                if next_t[m] == NEVER and queues[m]:
                    self._load(m)

    def refill(self) -> None:
        self._take()
        self._edges()

    # -- time ------------------------------------------------------------------------
    def _now_s(self) -> float:
        return self.clock.now()

    def deadline(self) -> int | None:
        d = min(self.due_t)
        return None if d == NEVER else d

    # -- one edge ----------------------------------------------------------------------
    def step(self, now: int) -> None:
        """Emit every step due at ``now`` (ticks), in the steps of the module's "Per step"."""
        slid = self._pick_due(now)
        due = self._due
        if not due:
            return
        outputs = self.io.outputs
        try:
            rise = outputs.rise(due)
        except HalError as exc:
            self._io_fault(due, exc)
            return
        width = self._account(rise, slid)
        try:
            outputs.fall(due, rise + width)
        except HalError as exc:
            self._io_fault(due, exc)
            return
        # the end stops after this step, in its direction and generation, before a motor
        # whose segment it ended reports DONE or goes on: a last step onto the switch is
        # an end stop hit, not a move done
        self._edges()
        self._look_at_ends()
        if self._done:
            self._go_on(rise)

    def _pick_due(self, now: int) -> bool:
        """The motors due at ``now`` into ``_due``: due, or planned within ``coalesce`` of
        now with nothing else holding it back (it shares this pulse); True: one slid."""
        due_t, next_t, slide_after = self.due_t, self.next_t, self.slide_after
        soon = now + self.coalesce
        due = self._due
        due.clear()
        slid = False
        for m in self.motors:
            d = due_t[m]
            if d <= now or (d <= soon and d == next_t[m]):
                if now - next_t[m] > slide_after[m]:
                    if not self._late(m, now):
                        continue  # stopped: a real motor may have lost steps
                    slid = True
                due.append(m)
        return slid

    def _account(self, rise: int, slid: bool) -> int:
        """While the STEP lines are high: lateness, positions, next steps (a segment's end
        into ``_done``), counters. The pulse width to keep."""
        record, pos, counters, dirs = self.stats.record_ns, self.pos, self.counters, self.dir
        left, iv, add, min_iv = self.left, self.iv, self.add, self.min_iv
        next_t, due_t, last_edge, prev_t = self.next_t, self.due_t, self.last_edge, self.prev_t
        widths, lateness, due = self.width, self.slid, self._due
        width, done = 0, self._done
        done.clear()
        for m in due:
            planned = next_t[m]
            if slid and lateness[m]:  # lateness is judged against the schedule before it slid
                record(rise - planned + lateness[m])
                lateness[m] = 0
            else:
                record(rise - planned)
            gap = rise - last_edge[m]
            if gap < _GAP_WINDOW:
                g = counters[MIN_GAP]
                if gap < g or not g:
                    counters[MIN_GAP] = gap
            pos[m] += dirs[m]
            prev_t[m] = planned
            last_edge[m] = rise
            if widths[m] > width:
                width = widths[m]
            n = left[m] - 1
            left[m] = n
            if n > 0:
                nt = planned + iv[m]
                next_t[m] = nt
                iv[m] += add[m]
                earliest = rise + min_iv[m]
                due_t[m] = nt if nt >= earliest else earliest
            else:
                next_t[m] = due_t[m] = NEVER
                done.append(m)
        counters[STEPS] += len(due)
        return width

    def _look_at_ends(self) -> None:
        """Each motor that stepped: the end stop ahead, and the one behind where it is
        watched for its release."""
        levels, ends, dirs = self.levels, self.ends, self.dir
        watch, release = self.watch, self.release
        for m in self._due:
            if watch[m]:
                line = ends[m][1 if dirs[m] > 0 else 0]
                if line is not None and levels[line] and self._check_endstop(m, line):
                    continue
            if release[m]:
                self._check_release(m)

    def _go_on(self, rise: int) -> None:
        """Each motor whose segment the step ended: DONE after a plan's last, its next one."""
        for m in self._done:
            if self.stopped_gen[m] == BLOCKED:
                continue  # stopped on its own account: nothing more until the answer
            if self.last[m]:  # before the next segment (a marker reports its own DONE)
                self.emit(ExecEvent(K.DONE, m, self.gen[m], self.pos[m], from_ticks(rise)))
            self._load(m)

    def _edges(self) -> None:
        try:
            edges = self.io.inputs.read_edges()
        except HalError as exc:
            self._io_fault(tuple(self.motors), exc)
            return
        for e in edges:  # a line's level and since when (its last edge)
            self.levels[e.line] = int(e.active)
            self.since[e.line] = to_ticks(e.t)

    def _check_endstop(self, m: int, line: int, gen: int = -1, d: int = 0, why: str = "") -> bool:
        """Motor m stepped toward ``line`` (or, ``why``, is about to in direction ``d`` in
        plan ``gen``), which is active: stop once it is debounced (True: stopped)."""
        since = self.since[line]
        if self.clock.now_ns() - since < self.debounce[m]:
            return False
        if gen < 0:  # a hit: by the step just made, in its plan and direction
            gen, d = self.gen[m], self.dir[m]
        self._halt(m)
        self.counters[ENDSTOPS] += 1
        t = from_ticks(max(since, 0))
        self.emit(ExecEvent(K.ENDSTOP, m, gen, self.pos[m], t, d, 0.0, why))
        return True

    def _on_end_ahead(self, m: int, gen: int, d: int) -> bool:
        """Before a segment's first step, the end stop ahead (``d``) active: stop, no step
        (ENDSTOP, :data:`ENDSTOP_ALREADY_ACTIVE`; True). A new plan reads the edges first."""
        line = self.ends[m][1 if d > 0 else 0]
        if line is None:
            return False
        if gen != self.gen[m]:
            self._edges()
            if self.stopped_gen[m] == BLOCKED:
                return True  # the read failed: faulted (every motor)
        on = self.levels[line] and self._check_endstop(m, line, gen, d, ENDSTOP_ALREADY_ACTIVE)
        return bool(on)

    def _check_release(self, m: int) -> None:
        """Motor m stepped away from the end stop behind it (homing's back-off): stop once
        that has been inactive for the debounce time; RELEASED says where it released (the
        first position seen off it; an unwired line is off it at the first step)."""
        line = self.ends[m][0 if self.dir[m] > 0 else 1]
        since = 0
        if line is not None:
            if self.levels[line]:
                self.rel_at[m] = NEVER  # still on it, or on it again (a bounce)
                return
            since = self.since[line]
        if self.rel_at[m] == NEVER or self.rel_since[m] != since:  # released by a new edge
            self.rel_at[m] = self.pos[m]
            self.rel_since[m] = since
        if self.clock.now_ns() - since < self.debounce[m]:
            return
        gen = self.gen[m]
        self._halt(m)
        t = from_ticks(max(since, 0))
        ev = ExecEvent(K.RELEASED, m, gen, self.pos[m], t, -self.dir[m], 0.0, "", self.rel_at[m])
        self.emit(ev)

    def _speed(self, m: int, planned: int) -> float:
        gap = planned - self.prev_t[m]
        return TICKS_PER_S / gap if 0 < gap < TICKS_PER_S else 0.0

    def _late(self, m: int, now: int) -> bool:
        """Motor m's step is late: slide the rest of its schedule by the lateness, or stop it
        where the lag that caused is one a real motor may not survive. False: stopped."""
        planned = self.next_t[m]
        late = now - planned
        gap = planned - self.prev_t[m]  # the interval this step ends: the motor's step rate
        rule = self.lag_rule[m]
        cells = self.mcells
        base = m * MOTOR_CELLS
        lag = rule.lag(late, gap)
        if late > cells[base + WORST_LATE]:
            cells[base + WORST_LATE] = late
        ulag = min(int(lag * LAG_UNIT), _CELL_MAX)
        if ulag > cells[base + WORST_LAG]:
            cells[base + WORST_LAG] = ulag
        if self.lag_faults[m] and rule.loses_steps(late, gap):
            cells[base + LAG_FAULTS] += 1
            rate = self._speed(m, planned)
            self._lost(
                m,
                now,
                f"step {late / 1000:.0f} us late at {rate:.0f} step/s: lag "
                f"{lag:.3f} full steps > max_lag_full_steps {rule.max_lag_full_steps:g} "
                f"({rule.microsteps} microsteps, start_speed "
                f"{rule.start_speed:g} step/s)",
                planned,
            )
            return False
        cells[base + SHIFT] += late
        cells[base + ABSORBED] += 1
        self.slid[m] = late
        self.next_t[m] = now  # (and the steps after it keep their intervals from here)
        return True

    def _lost(self, m: int, now: int, detail: str, planned: int | None = None) -> None:
        gen = self.gen[m]
        speed = self._speed(m, self.next_t[m] if planned is None else planned)
        self._halt(m)
        self.counters[TIMING_LOST] += 1
        t = from_ticks(now)
        self.emit(ExecEvent(K.TIMING_LOST, m, gen, self.pos[m], t, self.dir[m], speed, detail))

    def _io_fault(self, motors: Sequence[int], exc: Exception) -> None:
        self.counters[IO_ERRORS] += 1
        self._fault(motors, f"hardware error: {exc}")

    def _bad_records(self) -> None:
        """Records the transport found bad: a FAULT of their motors (every motor: -1)."""
        faults = self.inbox.faults
        while faults:
            m, detail = faults.popleft()
            self.counters[BAD_RECORDS] += 1
            self._fault(self.motors if m < 0 else (m,), detail)

    def _fault(self, motors: Sequence[int], detail: str) -> None:
        for m in motors:
            gen, t = self.gen[m], self.next_t[m]
            speed = 0.0 if t == NEVER else self._speed(m, t)
            self._halt(m)
            ev = ExecEvent(K.FAULT, m, gen, self.pos[m], self._now_s(), self.dir[m], speed, detail)
            self.emit(ev)

    def halt_all(self) -> None:
        for m in self.motors:
            self._halt(m)

    # -- drivers ---------------------------------------------------------------------
    def advance(self, now: int) -> None:
        """Virtual clock: do everything due up to ``now`` (the caller moves the clock)."""
        self.refill()
        self.step(now)
        self.refill()

    def run(
        self, running: Callable[[], bool], wait: Callable[[float], None], idle_s: float = 0.05
    ) -> None:
        """Real clock: the loop, until ``running()`` is False. End-stop edges are read after
        each step, before each wait and before a new plan's first step, not per turn."""
        now_ns = self.clock.now_ns
        counters = self.counters
        stops = self.inbox.stops
        due_t = self.due_t
        spin = self.spin
        take, step = self._take, self.step
        while running():
            counters[PROGRESS] += 1
            take()
            d = min(due_t)
            if d == NEVER:
                self._edges()
                wait(idle_s)
                continue
            now = now_ns()
            if d - now > spin:
                self._edges()
                wait(min((d - spin - now) / TICKS_PER_S, idle_s))
                continue
            while now < d and not stops:
                now = now_ns()
            if stops:
                continue
            step(now)
