"""A start's timeline (daemon/start/timeline.py): each step's own time, the line logged at READY,
and that line read back as bench/startup.py reads it. A clock the test turns."""

from __future__ import annotations

import pytest

from motorctl.daemon.start.timeline import StartTimeline, parse


class Clock:
    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def test_each_step_is_timed_from_the_one_before() -> None:
    clock = Clock(1000.0)
    t = StartTimeline("imported", clock)
    clock.now = 1000.0061
    t.mark("config")
    clock.now = 1000.0071
    t.mark("locks")
    clock.now = 1000.0321
    t.mark("executor ready")
    assert [(s, round(ms, 3)) for s, ms in t.steps_ms()] == [
        ("config", 6.1),
        ("locks", 1.0),
        ("executor ready", 25.0),
    ]
    assert t.text() == (
        "start-up: imported at 1000.000000 s (monotonic); config 6.1 ms, locks 1.0 ms, "
        "executor ready 25.0 ms"
    )


def test_the_logged_line_reads_back() -> None:
    clock = Clock(81234.5678905)
    t = StartTimeline("imported", clock)
    for step, at in (("config", 81234.58), ("status socket", 81234.6), ("threads", 81234.61)):
        clock.now = at
        t.mark(step)
    line = f"motorctld DEBUG motorctl: {t.text()}\n"
    first, at, steps = parse(line) or ("", 0.0, [])
    assert first == "imported"
    assert at == pytest.approx(81234.567890, abs=1e-6)
    assert [s for s, _ in steps] == ["config", "status socket", "threads"]
    assert [round(ms, 1) for _, ms in steps] == [12.1, 20.0, 10.0]


@pytest.mark.parametrize(
    "line",
    [
        "motorctld INFO motorctl: stopped",
        "start-up: imported at soon s (monotonic); config 1.0 ms",
        "start-up: imported at 12.5 s (monotonic); config fast ms",
    ],
)
def test_a_line_without_a_timeline_reads_as_none(line: str) -> None:
    assert parse(line) is None


def test_a_timeline_without_steps_reads_back_empty() -> None:
    t = StartTimeline("serve", Clock(5.0))
    assert parse(t.text()) == ("serve", 5.0, [])
