"""Pure motion-profile math: trapezoidal moves, runs, stops and their step times.

Units: steps, step/s, step/s^2, seconds. No I/O and no clocks: times are arguments.

A trajectory is a continuous piecewise-constant-acceleration curve s(t). The motor's integer
counter is the last integer touched: while s moves up the next step happens when s reaches
counter + 1, while it moves down when s reaches counter - 1. A trajectory that ends at rest on
an integer target therefore ends with a step exactly at its end time, at that target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "Segment",
    "Steps",
    "Trajectory",
    "plan_move_to",
    "plan_run",
    "plan_stop",
    "step_times_move_to",
]

# An integer this close (steps) to a segment end where the velocity reaches zero is crossed
# exactly at that segment's end time.
SNAP_TOLERANCE = 1e-6
# Relative tolerance of the contiguity checks of a Trajectory (times, positions, velocities).
_REL_TOL = 1e-9


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


def _close(x: float, y: float) -> bool:
    return abs(x - y) <= _REL_TOL * max(1.0, abs(x), abs(y))


@dataclass(frozen=True)
class Segment:
    """A piece of constant acceleration: s(t) = s0 + v0*tau + a*tau^2/2, tau = t - t0.

    ``duration`` is math.inf only for a final constant-velocity cruise (then ``a`` must be 0).
    ``position`` and ``velocity`` clamp ``t`` to [t0, t0 + duration].
    """

    t0: float
    duration: float
    s0: float
    v0: float
    a: float

    def __post_init__(self) -> None:
        for name in ("t0", "s0", "v0", "a"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"Segment.{name} must be finite")
        if math.isnan(self.duration) or self.duration < 0:
            raise ValueError("Segment.duration must be >= 0")
        if math.isinf(self.duration) and self.a != 0:
            raise ValueError("an infinite Segment must have a == 0 (constant-velocity cruise)")

    def _tau(self, t: float) -> float:
        return min(max(t - self.t0, 0.0), self.duration)

    def _position_at(self, tau: float) -> float:
        if math.isinf(tau):
            return self.s0 if self.v0 == 0 else math.copysign(math.inf, self.v0)
        return self.s0 + tau * (self.v0 + 0.5 * self.a * tau)

    def position(self, t: float) -> float:
        """Position at absolute time ``t`` (clamped to the segment)."""
        return self._position_at(self._tau(t))

    def velocity(self, t: float) -> float:
        """Velocity at absolute time ``t`` (clamped to the segment)."""
        tau = self._tau(t)
        return self.v0 if self.a == 0 else self.v0 + self.a * tau

    @property
    def end_time(self) -> float:
        """t0 + duration (math.inf for a cruise)."""
        return self.t0 + self.duration

    @property
    def end_position(self) -> float:
        """Position at the end; for a cruise +-inf in the direction of v0 (s0 if v0 == 0)."""
        return self._position_at(self.duration)

    @property
    def end_velocity(self) -> float:
        """Velocity at the end (v0 for a cruise)."""
        return self.v0 if self.a == 0 else self.v0 + self.a * self.duration

    @property
    def direction(self) -> int:
        """+1 / -1 for the direction of motion inside the segment, 0 if it does not move."""
        if self.duration == 0:
            return 0
        if math.isinf(self.duration):
            return _sign(self.v0)
        # The velocity does not change sign inside a segment, so the midpoint decides.
        return _sign(self.v0 + 0.5 * self.a * self.duration)


@dataclass(frozen=True)
class Trajectory:
    """Contiguous segments (in time and position; non-empty).

    The velocity never changes sign strictly inside a segment: a reversal through zero speed
    is a segment boundary. Only the last segment may be infinite (a cruise forever).
    ``position``/``velocity`` clamp: before the start they give the start state, after the end
    of a finite trajectory its end state; a final cruise is extrapolated.
    """

    segments: tuple[Segment, ...]

    def __post_init__(self) -> None:
        segs = self.segments
        if not segs:
            raise ValueError("a Trajectory needs at least one segment")
        for i, seg in enumerate(segs):
            if math.isinf(seg.duration) and i != len(segs) - 1:
                raise ValueError("only the last segment may be infinite")
            if math.isfinite(seg.duration) and seg.v0 != 0:
                ve = seg.end_velocity
                scale = abs(seg.v0) + abs(seg.a) * seg.duration
                if ve * seg.v0 < 0 and abs(ve) > _REL_TOL * scale:
                    raise ValueError(f"velocity changes sign inside segment {i}")
            if i:
                prev = segs[i - 1]
                if not (_close(prev.end_time, seg.t0) and _close(prev.end_position, seg.s0)):
                    raise ValueError(f"segment {i} is not contiguous with segment {i - 1}")

    def _segment_at(self, t: float) -> Segment:
        for seg in self.segments:
            if t < seg.end_time:
                return seg
        return self.segments[-1]

    def position(self, t: float) -> float:
        """Position at absolute time ``t`` (clamped, a final cruise is extrapolated)."""
        return self._segment_at(t).position(t)

    def velocity(self, t: float) -> float:
        """Velocity at absolute time ``t`` (clamped, a final cruise is extrapolated)."""
        return self._segment_at(t).velocity(t)

    @property
    def start_time(self) -> float:
        return self.segments[0].t0

    @property
    def start_position(self) -> float:
        return self.segments[0].s0

    @property
    def start_velocity(self) -> float:
        return self.segments[0].v0

    @property
    def end_time(self) -> float:
        """End time; math.inf for a run that cruises forever."""
        return self.segments[-1].end_time

    @property
    def end_position(self) -> float:
        """End position; for a moving cruise +-inf in its direction (never nan)."""
        return self.segments[-1].end_position

    @property
    def end_velocity(self) -> float:
        """End velocity (0 within rounding for a plan that ends at rest)."""
        return self.segments[-1].end_velocity

    @property
    def is_finite(self) -> bool:
        return math.isfinite(self.end_time)


class _Builder:
    """Appends contiguous segments; each starts where the previous one ends."""

    def __init__(self, t0: float, s0: float) -> None:
        self.t0 = t0
        self.elapsed = 0.0
        self.s = s0
        self.segments: list[Segment] = []

    def add(self, duration: float, v0: float, a: float) -> None:
        if not duration > 0:
            return
        seg = Segment(self.t0 + self.elapsed, duration, self.s, v0, a)
        self.segments.append(seg)
        self.elapsed += duration
        self.s = seg.end_position

    def build(self) -> Trajectory:
        if not self.segments:
            return Trajectory((Segment(self.t0, 0.0, self.s, 0.0, 0.0),))
        return Trajectory(tuple(self.segments))


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _check_finite(**values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")


def _add_stop(b: _Builder, v: float, dec: float) -> None:
    b.add(abs(v) / dec, v, -_sign(v) * dec)


def _add_approach(
    b: _Builder, target: float, w0: float, vmax: float, acc: float, dec: float
) -> None:
    """Time-optimal approach to rest at target, moving toward it at speed w0 >= 0.

    The caller guarantees the stopping distance w0^2/(2 dec) is not (noticeably) beyond target.
    """
    sigma = _sign(target - b.s)
    if sigma == 0:
        return
    if w0 > vmax:
        b.add((w0 - vmax) / dec, sigma * w0, -sigma * dec)
        w0 = vmax
    rem = max(sigma * (target - b.s), 0.0)
    peak_sq = (2.0 * rem * acc * dec + w0 * w0 * dec) / (acc + dec)
    vp = min(math.sqrt(max(peak_sq, 0.0)), vmax)
    if vp - w0 <= 1e-12 * vp:
        vp = w0
    b.add((vp - w0) / acc, sigma * w0, sigma * acc)
    if vp == 0:
        return
    cruise = sigma * (target - b.s) - vp * vp / (2.0 * dec)
    if cruise > 1e-12 * max(1.0, rem):
        b.add(cruise / vp, sigma * vp, 0.0)
    b.add(vp / dec, sigma * vp, -sigma * dec)


def plan_move_to(
    t0: float, s0: float, v0: float, target: float, vmax: float, acc: float, dec: float
) -> Trajectory:
    """Time-optimal trapezoid (triangular if short) from (s0, v0) at t0 to rest at target.

    Accelerates with acc, decelerates with dec; the speed never exceeds vmax except while an
    initial |v0| > vmax is brought down to vmax with dec. If v0 points away from target or
    its stopping distance v0^2/(2 dec) is beyond target, it first stops with dec and then plans
    from rest (reversing). Nothing to do (s0 == target, v0 == 0) gives a zero-length
    trajectory: one segment of duration 0 at rest. ValueError unless vmax, acc, dec > 0.
    """
    _check_positive(vmax=vmax, acc=acc, dec=dec)
    _check_finite(t0=t0, s0=s0, v0=v0, target=target)
    b = _Builder(t0, s0)
    w0 = 0.0
    if v0 != 0:
        sv = _sign(v0)
        stop_dist = v0 * v0 / (2.0 * dec)
        ahead = sv * (target - s0)
        if ahead <= 0 or ahead < stop_dist - 1e-9:
            _add_stop(b, v0, dec)
        else:
            w0 = abs(v0)
    _add_approach(b, target, w0, vmax, acc, dec)
    return b.build()


def plan_stop(t0: float, s0: float, v0: float, dec: float) -> Trajectory:
    """Decelerate with dec to rest (soft stop). From rest: a zero-length trajectory."""
    _check_positive(dec=dec)
    _check_finite(t0=t0, s0=s0, v0=v0)
    b = _Builder(t0, s0)
    _add_stop(b, v0, dec)
    return b.build()


def plan_run(
    t0: float,
    s0: float,
    v0: float,
    velocity: float,
    acc: float,
    dec: float,
    limit: float | None = None,
) -> Trajectory:
    """Continuous run at signed ``velocity``, then cruise forever (infinite last segment).

    Opposite v0: stop with dec, then accelerate with acc. Same direction: speed up with acc or
    slow down with dec to |velocity|. velocity == 0 is plan_stop (``limit`` ignored).

    With ``limit``: if sigma*(limit - s0) > 0 (sigma = sign(velocity)), the result is
    plan_move_to(t0, s0, v0, limit, |velocity|, acc, dec): it ends at rest exactly at limit
    and never crosses it unless v0 already heads to it too fast to stop in time (then it
    overshoots and comes back, as plan_move_to does). Otherwise (limit at or behind s0) it is
    plan_stop(t0, s0, v0, dec). ValueError unless acc, dec > 0.
    """
    _check_positive(acc=acc, dec=dec)
    _check_finite(t0=t0, s0=s0, v0=v0, velocity=velocity)
    if velocity == 0:
        return plan_stop(t0, s0, v0, dec)
    sigma = _sign(velocity)
    speed = abs(velocity)
    if limit is not None:
        _check_finite(limit=limit)
        if sigma * (limit - s0) <= 0:
            return plan_stop(t0, s0, v0, dec)
        return plan_move_to(t0, s0, v0, limit, speed, acc, dec)
    b = _Builder(t0, s0)
    w = sigma * v0
    if w < 0:
        _add_stop(b, v0, dec)
        w = 0.0
    if w < speed:
        b.add((speed - w) / acc, sigma * w, sigma * acc)
    elif w > speed:
        b.add((w - speed) / dec, sigma * w, -sigma * dec)
    b.add(math.inf, velocity, 0.0)
    return b.build()


class Steps:
    """Iterator over the integer crossings of a trajectory.

    ``counter`` is the motor's current integer position (the last integer touched); it must
    satisfy |s0 - counter| < 1 (+1e-6), else ValueError. Step times are closed form per
    segment and relative to the segment's t0.
    """

    def __init__(self, traj: Trajectory, counter: int) -> None:
        if not abs(traj.start_position - counter) < 1.0 + SNAP_TOLERANCE:
            raise ValueError(
                f"counter {counter} inconsistent with start position {traj.start_position}"
            )
        self._segments = traj.segments
        self._index = 0
        self._counter = int(counter)
        self._pending: tuple[float, int] | None = None

    @property
    def counter(self) -> int:
        return self._counter

    def peek(self) -> tuple[float, int] | None:
        """(time, direction) of the next step without advancing; None when there is none."""
        if self._pending is None:
            self._pending = self._find()
        return self._pending

    def next(self) -> tuple[float, int] | None:
        """(time, direction +1/-1) of the next step, advancing the counter; None at the end."""
        step = self.peek()
        if step is not None:
            self._counter += step[1]
            self._pending = None
        return step

    def __iter__(self) -> Steps:
        return self

    def __next__(self) -> tuple[float, int]:
        step = self.next()
        if step is None:
            raise StopIteration
        return step

    def _find(self) -> tuple[float, int] | None:
        segs = self._segments
        while self._index < len(segs):
            seg = segs[self._index]
            sigma = seg.direction
            if sigma == 0:
                self._index += 1
                continue
            d = sigma * (self._counter + sigma - seg.s0)
            w0 = max(sigma * seg.v0, 0.0)
            alpha = sigma * seg.a
            if math.isinf(seg.duration):
                length = math.inf
            else:
                length = sigma * (seg.end_position - seg.s0)
                stops = alpha < 0 and sigma * seg.end_velocity <= _REL_TOL * w0
                if stops and abs(d - length) <= SNAP_TOLERANCE:
                    return (seg.t0 + seg.duration, sigma)
            if d > length:
                self._index += 1
                continue
            if d <= 0:
                return (seg.t0, sigma)
            if alpha == 0:
                tau = d / w0
            else:
                root = math.sqrt(max(w0 * w0 + 2.0 * alpha * d, 0.0))
                tau = min(2.0 * d / (w0 + root), seg.duration)
            return (seg.t0 + tau, sigma)
        return None


def step_times_move_to(distance: int, vmax: float, acc: float, dec: float) -> list[float]:
    """Times (from 0) of each step of a move from rest at 0 to rest at ``distance``."""
    steps = Steps(plan_move_to(0.0, 0.0, 0.0, float(distance), vmax, acc, dec), 0)
    return [t for t, _ in steps]
