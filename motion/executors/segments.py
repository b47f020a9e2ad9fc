"""Step segments: a run of steps as (first, interval, count, add), integer ticks.

Klipper's ``queue_step`` idea (not its code): the planner sends, per motor, runs of steps
whose times follow ``t[0] = first``, ``t[k+1] = t[k] + interval[k]``, ``interval[0] =
interval``, ``interval[k+1] = interval[k] + add``. The executor then needs one integer
addition per step and no square root. :class:`SegmentCutter` makes the runs in closed form
from each constant-acceleration piece of a trajectory, every step within ``max_error``
ticks of its exact time, with no work per step.

Pure functions; no I/O, no clock. Used by the planner (the daemon's process).
"""

from __future__ import annotations

import math
from collections.abc import MutableSequence, Sequence
from typing import Any, NamedTuple


class StepSegment(NamedTuple):
    """``count`` steps in ``direction`` (+1/-1) of plan generation ``gen``.

    ``last``: the final segment of a finite plan (the executor reports DONE after it).
    ``watch``: the executor stops at the end stop ahead (off for stall homing).
    ``release``: the executor stops where the end stop behind releases (homing's back-off).
    """

    first: int
    interval: int
    count: int  # type: ignore[assignment]  # shadows tuple.count: a field name of the design
    add: int
    direction: int
    gen: int
    last: bool = False
    watch: bool = True
    release: bool = False

    def times(self) -> list[int]:
        out = []
        t, iv = self.first, self.interval
        for _ in range(self.count):
            out.append(t)
            t += iv
            iv += self.add
        return out


# -- closed-form cutting, one constant-acceleration piece at a time ----------------------

#: an integer this close (steps) to a piece's end where it comes to rest is crossed exactly
#: at the piece's end time (``motion.profile.SNAP_TOLERANCE``, repeated: pure module)
_SNAP = 1e-6
_REL_TOL = 1e-9
#: the quadratic through steps 0, k/2 and k of a run of k+1 steps is within
#: ``_INTERP * max|t'''| * k**3`` of the exact times (Lagrange remainder: 1/(72*sqrt(3)),
#: rounded up for the integer midpoint)
_INTERP = 0.0085


class Boundary(NamedTuple):
    """Where a handed-over segment starts: a plan can be cut there (see ``StepExecutor``).

    ``tick``: the segment's first step (exact, integer ns); ``t``: the same in seconds,
    unrounded; ``counter``: the step counter before that step; ``prev_t``: the time of the
    step before it (-inf for the first of a plan).
    """

    tick: int
    t: float
    counter: int
    prev_t: float


class SegmentCutter:
    """The steps of a trajectory cut into segments in closed form, a horizon at a time.

    The same steps as :class:`motorctl.motion.profile.Steps` (the integer crossings of the
    trajectory, the counter being the last integer touched), without iterating them: per
    constant-acceleration piece the step time of distance ``x`` is
    ``tau(x) = 2x / (w0 + sqrt(w0**2 + 2*alpha*x))`` (``x / w0`` at constant speed), and a
    run of steps becomes one segment whose quadratic ``(interval, add)`` goes through the
    exact times of its first, middle and last step. The length of a run comes from the
    error bound of that quadratic (the third derivative of ``tau``: ``3 alpha**2 / v**5``,
    largest where the piece is slowest) plus the rounding of ``interval`` and ``add`` to
    integer ticks, and is checked at two more steps. Cost: a few square roots per segment,
    nothing per step. No run is longer than ``max_span`` ticks, so a plan can be cut at a
    segment boundary soon after any moment (``StepExecutor.committed``).

    Owner: the planner (the engine lock). Pure: no clock, no I/O.
    """

    def __init__(self, pieces: Sequence[Any], counter: int, max_error: int, max_span: int) -> None:
        if pieces and not abs(pieces[0].s0 - counter) < 1.0 + _SNAP:
            raise ValueError(f"counter {counter} inconsistent with start position {pieces[0].s0}")
        self._pieces = pieces
        self._index = 0
        self.counter = int(counter)
        self.last_t = float("-inf")
        self.err = max_error
        self.span = max_span

    # -- the piece being cut ------------------------------------------------------
    def _next_step_distance(self) -> tuple[Any, int, float] | None:
        """(piece, sigma, distance of the next step in it); None when no step is left."""
        pieces = self._pieces
        while self._index < len(pieces):
            seg = pieces[self._index]
            sigma = seg.direction
            if sigma != 0:
                d = sigma * (self.counter + sigma - seg.s0)
                length = _length(seg, sigma)
                if d <= length or (_stops(seg, sigma) and d - length <= _SNAP):
                    return seg, sigma, d
            self._index += 1
        return None

    @property
    def done(self) -> bool:
        return self._next_step_distance() is None

    def cut(
        self,
        horizon: float,
        gen: int,
        watch: bool,
        bounds: MutableSequence[Boundary] | None = None,
        release: bool = False,
    ) -> list[StepSegment]:
        """Segments of every step up to ``horizon`` (seconds; at least the next step), their
        flags ``watch`` and ``release`` (:class:`StepSegment`)."""
        out: list[StepSegment] = []
        while True:
            nxt = self._next_step_distance()
            if nxt is None:
                break
            seg, sigma, d = nxt
            if seg.a == 0 and d > 0:  # a cruise: its runs in one tight loop
                more = self._cruise(seg, sigma, d, horizon, gen, watch, release, out, bounds)
                if more is False:
                    return out  # a step beyond the horizon is left: not the last segment
                if more:
                    continue
            n, first, interval, add, t_first, t_last = self._run(seg, sigma, d, horizon, not out)
            if n == 0:
                break
            if bounds is not None:
                bounds.append(Boundary(first, t_first, self.counter, self.last_t))
            out.append(StepSegment(first, interval, n, add, sigma, gen, False, watch, release))
            self.counter += sigma * n
            self.last_t = t_last
        if out and self.done:
            out[-1] = out[-1]._replace(last=True)
        return out

    def _cruise(
        self,
        seg: Any,
        sigma: int,
        d: float,
        horizon: float,
        gen: int,
        watch: bool,
        release: bool,
        out: list[StepSegment],
        bounds: MutableSequence[Boundary] | None,
    ) -> bool | None:
        """The runs of a constant-speed piece up to ``horizon``, appended to ``out``: the
        arithmetic of :meth:`_run` for ``alpha == 0``, without its calls, so a long cruise
        costs about a microsecond per segment. True: the piece is used up (cut on in the
        next); False: the horizon is reached; None: not handled here (a run whose interval
        rounds to 0, at over a step per ns), :meth:`_run` takes it from where this stopped.
        """
        t0, s0, v0, dur = seg.t0, seg.s0, seg.v0, seg.duration
        w0 = max(sigma * v0, 0.0)  # > 0: d > 0 is reached at constant speed
        length = _length(seg, sigma)
        finite = math.isfinite(length)
        tau_h = min(max(horizon - t0, 0.0), dur)
        x_h = sigma * ((s0 + tau_h * (v0 + 0.5 * seg.a * tau_h)) - s0)  # Segment.position
        span_s = self.span / 1e9
        cap = self._length_within_error(w0, 0.0, d, 1 << 62)  # the longest at this speed
        floor, new = math.floor, tuple.__new__  # (NamedTuples without their Python __new__)
        counter, last_t = self.counter, self.last_t
        try:
            while True:
                if finite and d > length:
                    return True
                t_d = t0 + d / w0
                if t_d > horizon and out:
                    return False
                first = round(t_d * 1_000_000_000)
                # the run: to the piece's end, the horizon and the span, within the error;
                # Segment.position at a == 0 is s0 + tau * v0 (v0 + 0.5*0*tau == v0 exactly)
                n = floor(x_h - d) + 1
                if n < 1:
                    n = 1
                if finite:
                    end = floor(length - d) + 1
                    if end < n:
                        n = end
                tau_s = t_d + span_s - t0  # > 0
                if tau_s > dur:
                    tau_s = dur
                by_span = floor(sigma * ((s0 + tau_s * v0) - s0) - d) + 1
                if by_span < n:
                    n = by_span
                if n < 1:
                    n = 1
                if n > cap:
                    n = cap
                if n == 1:
                    interval, t_end = 0, t_d
                else:
                    k2 = n - 1
                    t_end = t0 + (d + k2) / w0
                    interval = round((round(t_end * 1_000_000_000) - first) / k2)
                    if interval <= 0:
                        return None
                if bounds is not None:
                    bounds.append(new(Boundary, (first, t_d, counter, last_t)))
                seg_fields = (first, interval, n, 0, sigma, gen, False, watch, release)
                out.append(new(StepSegment, seg_fields))
                counter += sigma * n
                last_t = t_end
                d = sigma * (counter + sigma - s0)  # as _next_step_distance has it
        finally:
            self.counter, self.last_t = counter, last_t

    def _run(
        self, seg: Any, sigma: int, d: float, horizon: float, first_one: bool
    ) -> tuple[int, int, int, int, float, float]:
        """The next run of steps in ``seg``: (count, first, interval, add, t first, t last)."""
        _t0, length = seg.t0, _length(seg, sigma)
        w0 = max(sigma * seg.v0, 0.0)
        alpha = sigma * seg.a
        snap = _stops(seg, sigma)
        t_d = _time(seg, sigma, w0, alpha, d, length, snap)
        if t_d > horizon and not first_one:
            return 0, 0, 0, 0, 0.0, 0.0
        first = _ticks(t_d)
        if d <= 0 or (snap and abs(d - length) <= _SNAP):
            return 1, first, 0, 0, t_d, t_d  # a step on the piece's start or end: alone
        # regular steps d, d+1, ... <= length (the snapped last step is a run of its own)
        if snap and _near_int(length - d):
            avail = round(length - d)
        else:
            avail = math.floor(length - d) + 1 if math.isfinite(length) else 1 << 40
        # ... up to the horizon and the span
        x_h = sigma * (seg.position(horizon) - seg.s0)
        avail = min(avail, max(math.floor(x_h - d) + 1, 1))
        x_s = sigma * (seg.position(t_d + self.span / 1e9) - seg.s0)
        avail = max(min(avail, math.floor(x_s - d) + 1), 1)
        n = self._length_within_error(w0, alpha, d, avail)
        while True:
            if n == 1:
                return 1, first, 0, 0, t_d, t_d
            k2 = n - 1
            t_end = _time(seg, sigma, w0, alpha, d + k2, length, False)
            last = _ticks(t_end)
            if n == 2 or alpha == 0:
                add = 0
                interval = round((last - first) / k2)
            else:
                k1 = k2 // 2
                mid = _ticks(_time(seg, sigma, w0, alpha, d + k1, length, False)) - first
                a1, b1 = k1, k1 * (k1 - 1) / 2
                a2, b2 = k2, k2 * (k2 - 1) / 2
                add = round((a1 * (last - first) - a2 * mid) / (a1 * b2 - a2 * b1))
                interval = round((last - first - add * b2) / a2)
            # at constant speed the error is rounding only, within the bound by the length
            # chosen (``_length_within_error``): no check needed
            if (
                interval > 0
                and interval + add * (k2 - 1) > 0
                and (
                    alpha == 0
                    or self._checks(seg, sigma, w0, alpha, d, length, first, interval, add, k2)
                )
            ):
                return n, first, interval, add, t_d, t_end
            n = max(n // 2, 1)

    def _checks(
        self,
        seg: Any,
        sigma: int,
        w0: float,
        alpha: float,
        d: float,
        length: float,
        first: int,
        interval: int,
        add: int,
        k2: int,
    ) -> bool:
        for j in {k2 // 4, (3 * k2) // 4, k2}:
            exact = _ticks(_time(seg, sigma, w0, alpha, d + j, length, False))
            if abs(first + j * interval + add * (j * (j - 1) // 2) - exact) > self.err:
                return False
        return True

    def _length_within_error(self, w0: float, alpha: float, d: float, avail: int) -> int:
        """The longest run (<= avail) whose quadratic stays within the error bound."""
        err = self.err
        if alpha == 0:  # constant speed: only the interval's rounding, k/2 ticks
            return min(avail, 2 * max(err - 2, 1) + 1)

        def error(k: int) -> float:
            x = d + k if alpha < 0 else d  # the slowest end of the run
            v2 = w0 * w0 + 2.0 * alpha * x
            if v2 <= 0:
                return math.inf
            third = 3.0 * alpha * alpha / (v2 * v2 * math.sqrt(v2)) * 1e9  # ticks
            return _INTERP * third * k**3 + k * k / 16 + k / 2 + 2

        hi = min(avail, int(4 * math.sqrt(err)) + 2)
        if hi <= 2 or error(hi - 1) <= err:
            return max(hi, 1)
        lo = 2  # a run of 2 is always exact within rounding
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if error(mid - 1) <= err:
                lo = mid
            else:
                hi = mid
        return lo


def _ticks(t: float) -> int:
    return round(t * 1_000_000_000)


def _near_int(x: float) -> bool:
    return abs(x - round(x)) <= _SNAP


def _length(seg: Any, sigma: int) -> float:
    if math.isinf(seg.duration):
        return math.inf
    return float(sigma * (seg.end_position - seg.s0))


def _stops(seg: Any, sigma: int) -> bool:
    if math.isinf(seg.duration):
        return False
    w0 = max(sigma * seg.v0, 0.0)
    return bool(sigma * seg.a < 0 and sigma * seg.end_velocity <= _REL_TOL * w0)


def _time(
    seg: Any, sigma: int, w0: float, alpha: float, x: float, length: float, snap: bool
) -> float:
    """The time of the step at distance ``x`` into ``seg`` (the rules of ``Steps``)."""
    if snap and abs(x - length) <= _SNAP:
        return float(seg.t0 + seg.duration)
    if x <= 0:
        return float(seg.t0)
    if alpha == 0:
        return float(seg.t0 + x / w0)
    root = math.sqrt(max(w0 * w0 + 2.0 * alpha * x, 0.0))
    return float(seg.t0 + min(2.0 * x / (w0 + root), seg.duration))
