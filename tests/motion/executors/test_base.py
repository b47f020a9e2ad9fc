"""The executors' contract (motion/executors/base.py): the step path's integer time, and
what an executor that does not say otherwise offers (its own time is the clock's, no
late-step figures, no lateness histogram, no step core), and that one running on its own
refuses a virtual clock's calls by name."""

from __future__ import annotations

import pytest

from motorctl.motion.executors.base import TICKS_PER_S, from_ticks, to_ticks
from tests.support.executors import RecordingExecutor


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
