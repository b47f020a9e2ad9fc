"""Tests of motion.profile: trapezoid planning and integer step crossings."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from motorctl.motion.profile import (
    Segment,
    Steps,
    Trajectory,
    plan_move_to,
    plan_run,
    plan_stop,
    step_times_move_to,
)

FAST = settings(max_examples=80, deadline=None)

vmaxes = st.floats(min_value=1.0, max_value=5000.0)
ratios = st.floats(min_value=-3.0, max_value=3.0)


@st.composite
def limits(draw: st.DrawFn) -> tuple[float, float, float]:
    """(vmax, acc, dec) with ramps between 0.05 and 300 steps long, so tests stay fast."""
    vmax = draw(vmaxes)
    acc = vmax * vmax / (2 * draw(st.floats(min_value=0.05, max_value=300.0)))
    dec = vmax * vmax / (2 * draw(st.floats(min_value=0.05, max_value=300.0)))
    return vmax, acc, dec


distances = st.integers(min_value=-600, max_value=600)
Step = tuple[float, int, int]  # time, direction, counter after the step


# ---------------------------------------------------------------- helpers


def collect(traj: Trajectory, counter: int, horizon: float = math.inf) -> list[Step]:
    """All steps up to ``horizon`` with the counter after each one."""
    steps = Steps(traj, counter)
    out: list[Step] = []
    while True:
        nxt = steps.peek()
        if nxt is None or nxt[0] > horizon:
            return out
        assert steps.next() == nxt
        out.append((nxt[0], nxt[1], steps.counter))
        assert len(out) < 100_000


def check_steps(traj: Trajectory, counter: int, steps: list[Step]) -> None:
    """Strictly increasing times, one count per step, position equals the counter at each step."""
    prev_t = -math.inf
    c = counter
    for t, d, after in steps:
        assert t > prev_t
        assert traj.start_time <= t <= traj.end_time
        assert d in (1, -1)
        assert after == c + d
        c = after
        assert abs(traj.position(t) - c) <= 2e-6
        prev_t = t


def pieces(traj: Trajectory, horizon: float = math.inf) -> list[tuple[int, float, bool]]:
    """Monotone pieces (direction, end position, ends at rest) up to ``horizon``."""
    out: list[tuple[int, float, bool]] = []
    for seg in traj.segments:
        if seg.t0 >= horizon or seg.duration == 0:
            continue
        truncated = seg.end_time > horizon
        end = seg.position(horizon) if truncated else seg.end_position
        mid = seg.v0 if math.isinf(seg.duration) else seg.v0 + seg.a * seg.duration / 2
        d = (mid > 0) - (mid < 0)
        if d == 0:
            continue
        at_rest = not truncated and abs(seg.end_velocity) <= 1e-9 * max_speed(seg)
        if out and out[-1][0] == d:
            out[-1] = (d, end, at_rest)
        else:
            out.append((d, end, at_rest))
    return out


def expected_counts(traj: Trajectory, counter: int, horizon: float = math.inf) -> list[int]:
    """Integers crossed per monotone piece, from the piece extremes (independent of Steps).

    An integer within 1e-6 of a point where the motion stops counts as reached.
    """
    counts = []
    c = counter
    for d, end, at_rest in pieces(traj, horizon):
        tol = 1e-6 if at_rest else 0.0
        reached = math.floor(end + tol) if d > 0 else math.ceil(end - tol)
        n = max(0, d * (reached - c))
        c += d * n
        counts.append(n)
    return counts


def step_runs(steps: list[Step]) -> list[tuple[int, int]]:
    """Run-length encoding of the step directions: (direction, count)."""
    runs: list[tuple[int, int]] = []
    for _, d, _ in steps:
        if runs and runs[-1][0] == d:
            runs[-1] = (d, runs[-1][1] + 1)
        else:
            runs.append((d, 1))
    return runs


def check_counts(traj: Trajectory, counter: int, steps: list[Step], horizon: float) -> None:
    counts = expected_counts(traj, counter, horizon)
    expected = [(d, n) for (d, _, _), n in zip(pieces(traj, horizon), counts, strict=True) if n]
    assert step_runs(steps) == expected


def check_continuity(traj: Trajectory) -> None:
    segs = traj.segments
    for prev, seg in itertools.pairwise(segs):
        assert seg.t0 == pytest.approx(prev.end_time, rel=1e-12, abs=1e-12)
        assert seg.s0 == pytest.approx(prev.end_position, rel=1e-12, abs=1e-9)
        assert seg.v0 == pytest.approx(prev.end_velocity, rel=1e-9, abs=1e-9)
        assert seg.duration > 0


def check_ramps(traj: Trajectory, acc: float, dec: float) -> None:
    """Speeding up uses exactly acc, slowing down exactly dec."""
    for seg in traj.segments:
        if seg.a == 0:
            continue
        w0, w1 = abs(seg.v0), abs(seg.end_velocity)
        if w1 > w0:
            assert abs(seg.a) == acc
        else:
            assert abs(seg.a) == pytest.approx(dec, rel=1e-12)
            assert abs(seg.a) == dec


def max_speed(seg: Segment) -> float:
    return max(abs(seg.v0), abs(seg.end_velocity))


def exact_time(x: float, dist: float, vmax: float, acc: float, dec: float) -> float:
    """Time at which the exact rest-to-rest trapezoid from 0 to dist > 0 reaches x."""
    vp = min(vmax, math.sqrt(2 * dist * acc * dec / (acc + dec)))
    d_acc = vp * vp / (2 * acc)
    d_dec = vp * vp / (2 * dec)
    t_acc = vp / acc
    total = t_acc + (dist - d_acc - d_dec) / vp + vp / dec
    if x <= d_acc:
        return math.sqrt(2 * x / acc)
    if x <= dist - d_dec:
        return t_acc + (x - d_acc) / vp
    return total - math.sqrt(2 * max(dist - x, 0.0) / dec)


def optimal_duration(w0: float, dist: float, vmax: float, acc: float, dec: float) -> float:
    """Minimum time from speed w0 <= vmax toward a target at dist (stoppable) to rest there.

    The peak is found by bisection of (vp^2 - w0^2)/(2 acc) + vp^2/(2 dec) = dist.
    """
    lo, hi = w0, vmax
    if (hi * hi - w0 * w0) / (2 * acc) + hi * hi / (2 * dec) > dist:
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if (mid * mid - w0 * w0) / (2 * acc) + mid * mid / (2 * dec) > dist:
                hi = mid
            else:
                lo = mid
    vp = hi
    cruise = dist - (vp * vp - w0 * w0) / (2 * acc) - vp * vp / (2 * dec)
    return (vp - w0) / acc + max(cruise, 0.0) / vp + vp / dec


# ---------------------------------------------------------------- moves from rest


@FAST
@given(distances, limits())
def test_move_from_rest_step_count_and_order(dist: int, lim: tuple[float, float, float]) -> None:
    vmax, acc, dec = lim
    traj = plan_move_to(0.0, 0.0, 0.0, float(dist), vmax, acc, dec)
    steps = collect(traj, 0)
    check_steps(traj, 0, steps)
    check_continuity(traj)
    check_ramps(traj, acc, dec)
    assert len(steps) == abs(dist)
    assert all(d == (1 if dist > 0 else -1) for _, d, _ in steps)
    times = step_times_move_to(dist, vmax, acc, dec)
    assert times == [t for t, _, _ in steps]
    if dist:
        assert steps[-1][2] == dist
        assert steps[-1][0] == traj.end_time
        assert traj.end_position == pytest.approx(dist, abs=1e-9)
        assert traj.end_velocity == pytest.approx(0.0, abs=1e-9 * vmax)
    else:
        assert traj.end_time == traj.start_time == 0.0


@FAST
@given(distances, limits())
def test_speed_never_above_vmax(dist: int, lim: tuple[float, float, float]) -> None:
    vmax, acc, dec = lim
    times = step_times_move_to(dist, vmax, acc, dec)
    prev = 0.0
    for t in times:
        assert t - prev >= (1.0 / vmax) * (1 - 1e-9)
        prev = t
    traj = plan_move_to(0.0, 0.0, 0.0, float(dist), vmax, acc, dec)
    assert all(max_speed(seg) <= vmax * (1 + 1e-12) for seg in traj.segments)


@FAST
@given(st.integers(min_value=1, max_value=600), limits(), st.booleans())
def test_step_times_match_exact_trapezoid(
    dist: int, lim: tuple[float, float, float], negative: bool
) -> None:
    vmax, acc, dec = lim
    times = step_times_move_to(-dist if negative else dist, vmax, acc, dec)
    assert len(times) == dist
    exact = [exact_time(k, dist, vmax, acc, dec) for k in range(1, dist + 1)]
    total = exact[-1]
    for k, (t, e) in enumerate(zip(times, exact, strict=True), start=1):
        assert t == pytest.approx(e, abs=1e-9 * (1 + total))
        if k >= 10:
            assert t == pytest.approx(e, rel=1e-3)


@FAST
@given(st.integers(min_value=1, max_value=600), limits())
def test_symmetric_ramps_when_acc_equals_dec(dist: int, lim: tuple[float, float, float]) -> None:
    vmax, acc, _ = lim
    times = step_times_move_to(dist, vmax, acc, acc)
    intervals = [b - a for a, b in zip([0.0, *times], times, strict=False)]
    for a, b in zip(intervals, reversed(intervals), strict=True):
        assert a == pytest.approx(b, abs=1e-9 * (1 + times[-1]))


@FAST
@given(limits(), st.floats(min_value=0.01, max_value=0.99), st.booleans())
def test_triangular_when_too_short(
    lim: tuple[float, float, float], frac: float, negative: bool
) -> None:
    vmax, acc, dec = lim
    full = vmax * vmax / (2 * acc) + vmax * vmax / (2 * dec)
    dist = frac * full
    assume(dist >= 1e-3)
    target = -dist if negative else dist
    traj = plan_move_to(0.0, 0.0, 0.0, target, vmax, acc, dec)
    assert len(traj.segments) == 2
    peak = max(max_speed(seg) for seg in traj.segments)
    assert peak < vmax
    assert peak == pytest.approx(math.sqrt(2 * dist * acc * dec / (acc + dec)), rel=1e-9)
    assert traj.end_position == pytest.approx(target, rel=1e-9, abs=1e-9)
    assert traj.end_time == pytest.approx(peak / acc + peak / dec, rel=1e-9)


@FAST
@given(limits(), st.floats(min_value=1.01, max_value=20.0))
def test_trapezoid_cruises_at_vmax(lim: tuple[float, float, float], factor: float) -> None:
    vmax, acc, dec = lim
    dist = factor * (vmax * vmax / (2 * acc) + vmax * vmax / (2 * dec))
    traj = plan_move_to(5.0, 0.0, 0.0, dist, vmax, acc, dec)
    accel, cruise, decel = traj.segments
    assert (accel.a, cruise.a, decel.a) == (acc, 0.0, -dec)
    assert cruise.v0 == vmax
    cruise_len = dist - vmax * vmax / (2 * acc) - vmax * vmax / (2 * dec)
    assert cruise.duration == pytest.approx(cruise_len / vmax, rel=1e-9)
    assert traj.end_time == pytest.approx(5.0 + vmax / acc + cruise_len / vmax + vmax / dec)


def test_move_example_by_hand() -> None:
    # vmax 5, acc 10: 0.5 s ramp covering 1.25 steps, cruise 7.5 steps for 1.5 s.
    times = step_times_move_to(10, 5.0, 10.0, 10.0)
    assert times[0] == pytest.approx(math.sqrt(0.2))
    assert times[1] == pytest.approx(0.5 + 0.75 / 5)
    assert times[-1] == 2.5
    assert step_times_move_to(-10, 5.0, 10.0, 10.0) == times


def test_zero_move_is_zero_length() -> None:
    traj = plan_move_to(3.0, 7.0, 0.0, 7.0, 10.0, 10.0, 10.0)
    assert traj.segments == (Segment(3.0, 0.0, 7.0, 0.0, 0.0),)
    assert traj.is_finite and traj.start_time == traj.end_time == 3.0
    assert traj.end_position == 7.0
    steps = Steps(traj, 7)
    assert steps.peek() is None and steps.next() is None and steps.counter == 7
    assert step_times_move_to(0, 10.0, 10.0, 10.0) == []


def test_large_t0_keeps_precision() -> None:
    t0 = 1.0e6
    base = plan_move_to(0.0, 0.0, 0.0, 400.0, 3000.0, 20000.0, 15000.0)
    late = plan_move_to(t0, 0.0, 0.0, 400.0, 3000.0, 20000.0, 15000.0)
    a = collect(base, 0)
    b = collect(late, 0)
    assert len(a) == len(b) == 400
    for (ta, _, _), (tb, _, _) in zip(a, b, strict=True):
        assert tb - t0 == pytest.approx(ta, abs=1e-9)
    assert b[-1][0] == late.end_time


# ---------------------------------------------------------------- re-planning while moving


@FAST
@given(
    st.floats(min_value=-50.0, max_value=50.0),
    ratios,
    st.integers(min_value=-300, max_value=300),
    limits(),
    st.booleans(),
)
def test_move_from_moving_state(
    s0: float, ratio: float, target: int, lim: tuple[float, float, float], up: bool
) -> None:
    vmax, acc, dec = lim
    v0 = ratio * vmax
    counter = math.floor(s0) if up else math.ceil(s0)
    traj = plan_move_to(10.0, s0, v0, float(target), vmax, acc, dec)
    assert traj.start_position == s0 and traj.start_time == 10.0
    # Exact, except a subnormal v0 whose stop takes no representable time.
    assert traj.start_velocity == pytest.approx(v0, rel=0.0, abs=1e-300)
    check_continuity(traj)
    check_ramps(traj, acc, dec)
    assert traj.is_finite
    assert traj.end_position == pytest.approx(target, abs=1e-9)
    assert traj.end_velocity == pytest.approx(0.0, abs=1e-9 * (vmax + abs(v0)))

    # Speed: only an initial |v0| > vmax may exceed vmax, and it only decreases.
    segs = traj.segments
    first_over = abs(v0) > vmax
    for i, seg in enumerate(segs):
        if i == 0 and first_over:
            assert abs(seg.end_velocity) < abs(seg.v0)
            assert abs(seg.a) == dec
        else:
            assert max_speed(seg) <= vmax * (1 + 1e-12)

    # A reversal happens exactly when v0 points away or cannot stop in time.
    stop_dist = v0 * v0 / (2 * dec)
    ahead = math.copysign(1.0, v0) * (target - s0)
    dirs = [d for d, _, _ in pieces(traj)]
    assert len(dirs) <= 2
    if abs(v0) / dec > 0 and abs(ahead - stop_dist) > 1e-6:
        must_reverse = ahead <= 0 or ahead < stop_dist
        assert (len(dirs) == 2) == must_reverse
        if must_reverse:
            assert segs[0].end_velocity == pytest.approx(0.0, abs=1e-9 * abs(v0) + 1e-300)
            assert segs[0].end_position == pytest.approx(s0 + math.copysign(stop_dist, v0))
        elif not first_over:
            expected = optimal_duration(abs(v0), abs(target - s0), vmax, acc, dec)
            assert traj.end_time - 10.0 == pytest.approx(expected, rel=1e-6)

    steps = collect(traj, counter)
    check_steps(traj, counter, steps)
    check_counts(traj, counter, steps, math.inf)
    final = steps[-1][2] if steps else counter
    assert final == target
    if expected_counts(traj, counter)[-1:] not in ([], [0]):
        assert steps[-1][0] == traj.end_time


@FAST
@given(st.integers(min_value=1, max_value=200), limits(), st.booleans())
def test_overshoot_reverses_once(
    dist: int, lim: tuple[float, float, float], negative: bool
) -> None:
    vmax, acc, dec = lim
    sigma = -1 if negative else 1
    speed = math.sqrt(2 * dec * (dist + 3.5))  # cannot stop before the target
    traj = plan_move_to(0.0, 0.0, sigma * speed, float(sigma * dist), vmax, acc, dec)
    steps = collect(traj, 0)
    check_steps(traj, 0, steps)
    runs = step_runs(steps)
    assert runs == [(sigma, dist + 3), (-sigma, 3)]
    assert steps[-1][2] == sigma * dist
    assert steps[-1][0] == traj.end_time
    assert max(sigma * seg.end_position for seg in traj.segments) == pytest.approx(dist + 3.5)


def test_reversal_counter_consistency() -> None:
    # Moving down at 40 step/s from 2.25 toward +5: stop 4 steps lower (dec 200), come back.
    traj = plan_move_to(0.0, 2.25, -40.0, 5.0, 50.0, 100.0, 200.0)
    assert traj.segments[0].end_position == pytest.approx(-1.75)
    steps = collect(traj, 2)
    counters = [c for _, _, c in steps]
    assert counters == [1, 0, -1, 0, 1, 2, 3, 4, 5]
    assert [d for _, d, _ in steps] == [-1, -1, -1, 1, 1, 1, 1, 1, 1]
    check_steps(traj, 2, steps)


def test_reversal_on_an_integer_steps_once_there() -> None:
    # Stops exactly at -2 (v0^2 / 2 dec = 4), touches it once, then comes back up.
    traj = plan_move_to(0.0, 2.0, -40.0, 3.0, 50.0, 100.0, 200.0)
    steps = collect(traj, 2)
    assert [c for _, _, c in steps] == [1, 0, -1, -2, -1, 0, 1, 2, 3]
    assert steps[3][0] == traj.segments[0].end_time
    assert steps[-1][0] == traj.end_time


@FAST
@given(st.floats(min_value=1.1, max_value=4.0), limits(), st.booleans())
def test_over_vmax_slows_to_vmax_first(
    factor: float, lim: tuple[float, float, float], negative: bool
) -> None:
    vmax, acc, dec = lim
    sigma = -1 if negative else 1
    v0 = sigma * factor * vmax
    dist = v0 * v0 / (2 * dec) + 50.0
    traj = plan_move_to(0.0, 0.0, v0, sigma * dist, vmax, acc, dec)
    first, *rest = traj.segments
    assert first.a == -sigma * dec
    assert first.end_velocity == pytest.approx(sigma * vmax)
    assert all(max_speed(seg) <= vmax * (1 + 1e-12) for seg in rest)
    assert [d for d, _, _ in pieces(traj)] == [sigma]


# ---------------------------------------------------------------- runs


@FAST
@given(st.floats(min_value=-20.0, max_value=20.0), ratios, ratios, limits())
def test_run_changes_speed_and_reverses(
    s0: float, r0: float, r1: float, lim: tuple[float, float, float]
) -> None:
    vmax, acc, dec = lim
    v0, velocity = r0 * vmax, r1 * vmax
    assume(abs(velocity) >= 1e-6)  # keeps the 200-step horizon finite
    traj = plan_run(0.0, s0, v0, velocity, acc, dec)
    check_continuity(traj)
    check_ramps(traj, acc, dec)
    last = traj.segments[-1]
    assert not traj.is_finite and traj.end_time == math.inf
    assert (last.v0, last.a, last.duration) == (velocity, 0.0, math.inf)
    assert traj.end_position == math.copysign(math.inf, velocity)
    assert traj.end_velocity == velocity
    top = max(abs(v0), abs(velocity)) * (1 + 1e-12)
    assert all(max_speed(seg) <= top for seg in traj.segments)
    # (a v0 so tiny that its stop takes no representable time does not count)
    reverses = ((v0 > 0 > velocity) or (v0 < 0 < velocity)) and abs(v0) / dec > 0
    assert (traj.segments[0].end_velocity == pytest.approx(0.0, abs=1e-9 * vmax)) or not reverses
    assert len(pieces(traj)) == (2 if reverses else 1)

    ramp_end = last.t0
    sigma = 1 if velocity > 0 else -1
    halfway = math.floor(last.s0) + 0.5 + sigma * 200  # no integer crossing near the horizon
    horizon = ramp_end + (halfway - last.s0) / velocity
    counter = math.floor(s0)
    steps = collect(traj, counter, horizon)
    check_steps(traj, counter, steps)
    check_counts(traj, counter, steps, horizon)
    assert traj.position(horizon) == pytest.approx(
        last.s0 + velocity * (horizon - ramp_end), rel=1e-12
    )


def test_run_examples() -> None:
    up = plan_run(0.0, 0.0, 0.0, 100.0, 50.0, 25.0)
    assert [(s.a, s.duration) for s in up.segments] == [(50.0, 2.0), (0.0, math.inf)]
    slower = plan_run(1.0, 0.0, 100.0, 20.0, 50.0, 25.0)
    assert [(s.a, s.duration) for s in slower.segments] == [(-25.0, 3.2), (0.0, math.inf)]
    rev = plan_run(0.0, 0.0, 100.0, -50.0, 50.0, 25.0)
    assert [(s.v0, s.a, s.duration) for s in rev.segments] == [
        (100.0, -25.0, 4.0),
        (0.0, -50.0, 1.0),
        (-50.0, 0.0, math.inf),
    ]
    assert rev.position(4.0) == pytest.approx(200.0)
    assert rev.position(15.0) == pytest.approx(200.0 - 25.0 - 50.0 * 10.0)
    steps = collect(rev, 0, 4.5)
    assert [c for _, _, c in steps][198:] == [199, 200, 199, 198, 197, 196, 195, 194]


@FAST
@given(
    st.floats(min_value=-20.0, max_value=20.0),
    ratios,
    st.integers(min_value=1, max_value=300),
    limits(),
    st.booleans(),
)
def test_run_with_limit_stops_at_limit(
    s0: float, r0: float, ahead: int, lim: tuple[float, float, float], negative: bool
) -> None:
    vmax, acc, dec = lim
    sigma = -1 if negative else 1
    velocity = sigma * vmax
    v0 = r0 * vmax
    limit = float((math.floor(s0) if sigma > 0 else math.ceil(s0)) + sigma * ahead)
    if v0 * sigma > 0:  # keep the stop before the limit feasible
        assume(v0 * v0 / (2 * dec) <= sigma * (limit - s0))
    traj = plan_run(0.0, s0, v0, velocity, acc, dec, limit=limit)
    assert traj == plan_move_to(0.0, s0, v0, limit, vmax, acc, dec)
    check_continuity(traj)
    assert traj.is_finite
    assert traj.end_position == pytest.approx(limit, abs=1e-9)
    extremes = [sigma * seg.end_position for seg in traj.segments]
    assert max(extremes) <= sigma * limit + 1e-9
    counter = round(s0)
    steps = collect(traj, counter)
    check_steps(traj, counter, steps)
    assert all(sigma * c <= sigma * limit for _, _, c in steps)
    assert (steps[-1][2] if steps else counter) == limit
    if steps and expected_counts(traj, counter)[-1] > 0:
        assert steps[-1][0] == traj.end_time
    for seg in traj.segments[1:]:
        assert max_speed(seg) <= vmax * (1 + 1e-12)


@FAST
@given(st.floats(min_value=-20.0, max_value=20.0), ratios, st.floats(0.0, 30.0), limits())
def test_run_with_limit_behind_is_a_stop(
    s0: float, r0: float, back: float, lim: tuple[float, float, float]
) -> None:
    vmax, acc, dec = lim
    v0 = r0 * vmax
    for sigma in (1, -1):
        traj = plan_run(2.0, s0, v0, sigma * vmax, acc, dec, limit=s0 - sigma * back)
        assert traj == plan_stop(2.0, s0, v0, dec)


def test_run_zero_velocity_is_a_stop() -> None:
    assert plan_run(0.0, 1.0, 30.0, 0.0, 10.0, 20.0) == plan_stop(0.0, 1.0, 30.0, 20.0)
    assert plan_run(0.0, 1.0, 30.0, 0.0, 10.0, 20.0, limit=5.0) == plan_stop(0.0, 1.0, 30.0, 20.0)


# ---------------------------------------------------------------- stops


@FAST
@given(st.floats(min_value=-20.0, max_value=20.0), ratios, limits(), st.booleans())
def test_stop_within_stopping_distance(
    s0: float, ratio: float, lim: tuple[float, float, float], up: bool
) -> None:
    vmax, _, dec = lim
    v0 = ratio * vmax
    traj = plan_stop(7.0, s0, v0, dec)
    stop_dist = v0 * v0 / (2 * dec)
    end = s0 + math.copysign(stop_dist, v0)
    assert traj.end_position == pytest.approx(end, abs=1e-9, rel=1e-12)
    assert traj.end_time == pytest.approx(7.0 + abs(v0) / dec)
    assert traj.end_velocity == pytest.approx(0.0, abs=1e-9 * vmax)
    check_continuity(traj)
    counter = math.floor(s0) if up else math.ceil(s0)
    steps = collect(traj, counter)
    check_steps(traj, counter, steps)
    check_counts(traj, counter, steps, math.inf)
    assert len(steps) <= math.floor(stop_dist + 1e-6) + 1  # +1e-6: the snap at rest
    assert all(d == (1 if v0 > 0 else -1) for _, d, _ in steps)


def test_stop_examples() -> None:
    traj = plan_stop(0.0, 0.0, 10.0, 10.0)  # stops exactly at 5
    steps = collect(traj, 0)
    assert [c for _, _, c in steps] == [1, 2, 3, 4, 5]
    assert steps[-1][0] == traj.end_time == 1.0
    rest = plan_stop(4.0, 2.5, 0.0, 10.0)
    assert rest.segments == (Segment(4.0, 0.0, 2.5, 0.0, 0.0),)
    assert collect(rest, 2) == []


# ---------------------------------------------------------------- data types


def test_segment_and_trajectory_accessors() -> None:
    seg = Segment(1.0, 2.0, 10.0, 4.0, -2.0)
    assert seg.end_time == 3.0
    assert seg.end_position == 14.0
    assert seg.end_velocity == 0.0
    assert seg.position(2.0) == 13.0 and seg.velocity(2.0) == 2.0
    assert seg.position(0.0) == 10.0 and seg.position(9.0) == 14.0
    traj = Trajectory((seg, Segment(3.0, 1.0, 14.0, 0.0, -4.0)))
    assert traj.start_time == 1.0 and traj.end_time == 4.0 and traj.is_finite
    assert traj.position(-5.0) == 10.0 and traj.velocity(-5.0) == 4.0
    assert traj.position(3.5) == 13.5 and traj.velocity(3.5) == -2.0
    assert traj.position(100.0) == 12.0 and traj.velocity(100.0) == -4.0
    cruise = Trajectory((Segment(0.0, math.inf, 1.0, -3.0, 0.0),))
    assert cruise.position(10.0) == -29.0
    assert cruise.end_position == -math.inf and cruise.end_time == math.inf
    assert not cruise.is_finite
    still = Trajectory((Segment(0.0, math.inf, 1.0, 0.0, 0.0),))
    assert still.end_position == 1.0
    assert Steps(still, 1).next() is None


@pytest.mark.parametrize(
    "segments",
    [
        (),
        (Segment(0.0, 1.0, 0.0, 1.0, 0.0), Segment(1.5, 1.0, 1.0, 1.0, 0.0)),  # time gap
        (Segment(0.0, 1.0, 0.0, 1.0, 0.0), Segment(1.0, 1.0, 2.0, 1.0, 0.0)),  # position jump
        (Segment(0.0, 2.0, 0.0, 1.0, -1.0),),  # sign change inside
        (Segment(0.0, math.inf, 0.0, 1.0, 0.0), Segment(5.0, 1.0, 5.0, 1.0, 0.0)),  # inf not last
    ],
)
def test_invalid_trajectories(segments: tuple[Segment, ...]) -> None:
    with pytest.raises(ValueError):
        Trajectory(segments)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"duration": -1.0},
        {"duration": math.nan},
        {"duration": math.inf, "a": 1.0},
        {"s0": math.nan},
        {"v0": math.inf},
    ],
)
def test_invalid_segments(kwargs: dict[str, float]) -> None:
    args: dict[str, float] = {"t0": 0.0, "duration": 1.0, "s0": 0.0, "v0": 0.0, "a": 0.0}
    args.update(kwargs)
    with pytest.raises(ValueError):
        Segment(**args)


def test_steps_peek_and_counter_checks() -> None:
    traj = plan_move_to(0.0, 0.0, 0.0, -3.0, 10.0, 10.0, 10.0)
    steps = Steps(traj, 0)
    first = steps.peek()
    assert first is not None and first[1] == -1
    assert steps.peek() == first and steps.counter == 0
    assert steps.next() == first and steps.counter == -1
    assert [d for _, d in steps] == [-1, -1]
    assert steps.counter == -3 and steps.next() is None and steps.peek() is None
    with pytest.raises(ValueError):
        Steps(traj, 2)
    with pytest.raises(ValueError):
        Steps(plan_move_to(0.0, 0.5, 0.0, 3.0, 10.0, 10.0, 10.0), -1)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_value_errors(bad: float) -> None:
    with pytest.raises(ValueError):
        plan_move_to(0.0, 0.0, 0.0, 10.0, bad, 1.0, 1.0)
    with pytest.raises(ValueError):
        plan_move_to(0.0, 0.0, 0.0, 10.0, 1.0, bad, 1.0)
    with pytest.raises(ValueError):
        plan_move_to(0.0, 0.0, 0.0, 10.0, 1.0, 1.0, bad)
    with pytest.raises(ValueError):
        plan_run(0.0, 0.0, 0.0, 10.0, bad, 1.0)
    with pytest.raises(ValueError):
        plan_run(0.0, 0.0, 0.0, 10.0, 1.0, bad)
    with pytest.raises(ValueError):
        plan_stop(0.0, 0.0, 1.0, bad)
    with pytest.raises(ValueError):
        step_times_move_to(5, bad, 1.0, 1.0)
