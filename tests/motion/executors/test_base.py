"""The executors' contract (motion/executors/base.py): the step path's integer time, and
what an executor that does not say otherwise offers (its own time is the clock's, no
late-step figures, no lateness histogram, no step core), and that one running on its own
refuses a virtual clock's calls by name; the one lag rule (``LagRule``), and the per-motor
values it takes always given (their defaults are the config model's only)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from motorctl.daemon.start.platform_check import MotorRate
from motorctl.motion.executors.base import (
    TICKS_PER_S,
    AxisLimits,
    LagRule,
    from_ticks,
    lag_full_steps,
    to_ticks,
)
from motorctl.motion.types import MotorParams
from tests.support.executors import RecordingExecutor
from tests.support.motor_defaults import declared

LAG_VALUES = ("start_speed", "max_lag_full_steps")


def test_ticks_are_nanoseconds_rounded_to_the_nearest() -> None:
    assert TICKS_PER_S == 1_000_000_000
    assert to_ticks(1.5) == 1_500_000_000 and to_ticks(2.4e-9) == 2 and to_ticks(2.6e-9) == 3
    assert from_ticks(to_ticks(0.123456789)) == pytest.approx(0.123456789, abs=1e-12)


def test_what_an_executor_offers_unless_it_says_otherwise() -> None:
    ex = RecordingExecutor(2)
    assert ex.motors == 2 and ex.motor_time(1, 5.0) == 5.0
    assert ex.motor_timing(0) == {} and ex.step_lateness() is None and ex.step_core() is None
    ex.on_event()  # a no-op until the engine sets its own
    with pytest.raises(TypeError, match="RecordingExecutor does not run on a virtual clock"):
        ex.next_deadline()
    with pytest.raises(TypeError, match="does not run on a virtual clock"):
        ex.advance(1.0)


def test_the_lag_rule_stops_above_the_start_speed_beyond_the_tolerance() -> None:
    rule = LagRule(16, 100.0, 0.5)
    gap = TICKS_PER_S // 10_000  # 10,000 step/s: 0.5 full steps = 800 us late
    assert rule.lag(800_000, gap) == pytest.approx(0.5)
    assert not rule.loses_steps(800_000, gap) and rule.loses_steps(800_001, gap)
    assert rule.loses_steps_at(801e-6, 10_000.0) and not rule.loses_steps_at(799e-6, 10_000.0)
    slow = TICKS_PER_S // 50  # below the start speed: any lag slides
    assert rule.lag(TICKS_PER_S, slow) > 0.5 and not rule.loses_steps(TICKS_PER_S, slow)
    assert rule.lag(10**6, TICKS_PER_S) == 0.0  # not moving
    assert rule.fastest_safe_rate(800e-6) == pytest.approx(10_000.0)
    assert LagRule(16, 100_000.0, 0.5).fastest_safe_rate(800e-6) == 100_000.0
    for start in (0.0, 5e-324, 0.5, 1.0):  # any motion is above it (no overflow either)
        assert LagRule(16, start, 0.5).start_gap == TICKS_PER_S


@given(
    late_us=st.floats(1.0, 1e5),
    rate=st.floats(2.0, 2e5),
    micro=st.sampled_from([1, 2, 16, 256]),
    start=st.floats(0.0, 1e5),
    tolerance=st.floats(0.01, 64.0),
)
def test_the_rule_in_seconds_is_the_rule_in_ticks(
    late_us: float, rate: float, micro: int, start: float, tolerance: float
) -> None:
    """The platform check asks in seconds and step/s, the step core in ticks: one rule."""
    rule = LagRule(micro, start, tolerance)
    lag = lag_full_steps(late_us * 1e-6, 1 / rate, micro)
    late_s = late_us * 1e-6
    assert rule.loses_steps_at(late_s, rate) == rule.loses_steps(
        late_s * TICKS_PER_S, TICKS_PER_S / rate
    )
    # the former formula, away from the edges (the start gap is whole ticks: up to 5e-5 of
    # the start speed apart at 100,000 step/s)
    if abs(lag - tolerance) > 1e-9 * tolerance and abs(rate - start) > 1e-4 * max(start, 1):
        assert rule.loses_steps_at(late_us * 1e-6, rate) == (lag > tolerance and rate > start)


@pytest.mark.parametrize(
    ("record", "name"),
    [
        *((r, n) for r in (MotorParams, AxisLimits, MotorRate) for n in LAG_VALUES),
        *((MotorParams, n) for n in ("steps_per_rev", "queue_depth", "max_waypoints")),
        (MotorParams, "max_speed"),
        (MotorParams, "microsteps"),
        (AxisLimits, "microsteps"),
    ],
)
def test_a_motors_values_have_no_default_but_the_config_models(record: type, name: str) -> None:
    """Written once: [[motors]] declares them (daemon/config/model.py); a default here again
    could disagree with it (start_speed was 100 in one record, 0.0 in another)."""
    field = {f.name: f for f in dataclasses.fields(record)}[name]
    assert field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING
    if name != "microsteps":  # optional: the driver chip's, else MICROSTEPS_UNSAID
        assert declared(name) is not None
