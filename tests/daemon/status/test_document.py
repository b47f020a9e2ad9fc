"""The status document (daemon/status/document.py) of a live daemon (in-process, thread
executor, link on a real PTY), read through its socket: it is complete, a read takes no
motion lock, the whole histogram comes only when asked, a soft stop says how soon its
deceleration took over; and systemd's one-line summary of documents. (How fast reads are
is a figure, not a test: bench/status_rate.py.)"""

from __future__ import annotations

import errno
import itertools
import math
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.status.document import summary_line
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer
from motorctl.motion.latency import BINS
from motorctl.protocol.codec import Move, StopMove, WaitMoved
from tests.support.inprocess import LIVE_CONFIG, TWO_MOTORS, LiveDaemon
from tests.support.wait import until

READ_DEADLINE_S = 10.0  # a loaded 2-core machine; a read waiting for the lock never ends

MOTOR_KEYS = {
    "index",
    "name",
    "state",
    "position",
    "queued",
    "fault",
    "position_lost",
    "waypoints",
    "faults",
    "timing",
    "soft_stops",
    "speed",
}
#: each motor's late-step figures and rule (docs/timing.md, "Reading the figures")
TIMING_KEYS = {
    "late_absorbed",
    "slid_ms",
    "worst_late_us",
    "worst_lag_full_steps",
    "lag_faults",
    "microsteps",
    "max_lag_full_steps",
}
#: what bench/steps.py, bench/latency.py, docs/timing.md and the tests read from ``steps``
STEP_KEYS = {
    "steps",
    "p50_us",
    "p99_us",
    "p999_us",
    "max_us",
    "late",
    "late_threshold_us",
    "timing_lost",
    "min_gap_ns",
    "segments_discarded",
    "io_errors",
    "endstops",
    "bad_records",
    "progress",
}


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[LiveDaemon, Path]]:
    live = LiveDaemon(tmp_path, LIVE_CONFIG, motion=True)
    path = tmp_path / "status.sock"
    server = StatusServer(path, live.daemon.status)
    server.start()
    try:
        yield live, path
    finally:
        server.close()
        assert live.alive(), "a daemon thread died"
        live.close()


def nearest_rank(histogram: dict[int, int], q: float) -> float:
    keys = sorted(histogram)
    cum = list(itertools.accumulate(histogram[k] for k in keys))
    exact = q / 100 * cum[-1]
    rank = max(1, math.ceil(exact - 1e-12 * exact))
    return float(next(k for k, c in zip(keys, cum, strict=True) if c >= rank))


def test_status_is_complete_and_the_histogram_comes_when_asked(
    served: tuple[LiveDaemon, Path],
) -> None:
    live, path = served
    live.moving(0)
    doc = read_status(path, timeout=READ_DEADLINE_S)
    assert {"motors", "steps", "executor", "clamped", "state", "link"} <= set(doc)
    assert [m["index"] for m in doc["motors"]] == [0, 1]
    assert all(set(m) >= MOTOR_KEYS for m in doc["motors"])
    assert all(set(m["timing"]) == TIMING_KEYS for m in doc["motors"])
    assert doc["motors"][0]["soft_stops"] == {
        "count": 0,
        "takeover_ms": [0.0, 0.0],
        "takeover_steps": [0, 0],
    }
    assert doc["motors"][0]["state"] != "idle" and doc["motors"][0]["fault"] is None
    assert doc["motors"][0]["speed"] > 0 and doc["motors"][1]["speed"] == 0
    assert doc["pins"] == [{"number": 0, "output": True, "level": False}]
    assert doc["dc"] is None  # none configured
    assert doc["uptime_s"] > 0 and doc["monotonic_s"] > 0 and doc["unix_s"] > 0
    last = doc["link"]["recent"][-1]  # moving() asked for the position until it moved
    assert last["command"] == "GetAbsPos(motor=0)" and last["result"].startswith("pos=")
    assert set(doc["steps"]) >= STEP_KEYS and doc["steps"]["steps"] > 0
    assert "histogram_us" not in doc["steps"]  # bounded cost unless asked
    realtime = doc["executor"].pop("realtime")
    assert doc["executor"] == {
        "alive": True,
        "reason": None,
        "kind": "thread",
        "core": "python",
        "pid": None,
    }
    # a test daemon asks for no real time: each request "not asked", with the setting
    assert realtime["refused"] == [] and realtime["kernel"]["release"] == os.uname().release
    assert realtime["sched_fifo"] == {
        "state": "not asked",
        "what": "[step_thread] priority = 0",
        "error": None,
        "reason": None,
        "fix": None,
    }
    assert {"counters", "processing"} <= set(doc["link"])
    # the link's processing: reads, and those over the target (nothing late: nothing is due)
    assert {"reads", "over_target", "target_us"} <= set(doc["link"]["processing"])
    assert not {"steps", "late"} & set(doc["link"]["processing"])
    assert doc["state"]["ok"] is True
    assert live.code(StopMove(0, True)) is None
    assert live.code(WaitMoved(0, 20_000)) is None
    full = read_status(path, timeout=READ_DEADLINE_S, histogram=True)
    steps = full["steps"]
    histogram = {int(us): n for us, n in steps["histogram_us"].items()}
    assert sum(histogram.values()) == steps["steps"] > 0  # at rest: one snapshot
    for name, q in (("p50_us", 50), ("p99_us", 99), ("p999_us", 99.9)):
        expected = nearest_rank(histogram, q)  # the summary agrees (beyond: the maximum)
        assert steps[name] == expected if expected < BINS else steps[name] >= BINS, name
    plain = read_status(path, timeout=READ_DEADLINE_S)["steps"]
    moving_on = ("histogram_us", "progress")  # progress: the core's turns, also at rest
    assert {k: v for k, v in plain.items() if k not in moving_on} == {
        k: v for k, v in steps.items() if k not in moving_on
    }


def test_a_status_read_takes_no_motion_lock(served: tuple[LiveDaemon, Path]) -> None:
    """While something holds the engine lock (planning, a command), status still answers:
    a read that waited for the lock would time out here."""
    live, path = served
    assert live.code(Move(1, True, 1, 0, 0)) is None
    until(
        "motor 1 stepping",
        lambda: read_status(path, timeout=READ_DEADLINE_S)["motors"][1]["position"] > 0,
    )
    with live.daemon.engine.lock:
        doc = read_status(path, timeout=READ_DEADLINE_S)
        full = read_status(path, timeout=READ_DEADLINE_S, histogram=True)
    assert doc["motors"][1]["state"] != "idle" and doc["executor"]["alive"]
    assert sum(full["steps"]["histogram_us"].values()) > 0


def test_a_soft_stop_reports_how_soon_the_deceleration_took_over(
    served: tuple[LiveDaemon, Path],
) -> None:
    """A soft StopMove re-plans from the executed state: the deceleration takes over at the
    first segment boundary after the executor's lead, within lead + one segment's span + one
    step of the command (a run holds the steps within its span; the next starts at the step
    after its last), and the motor's status says how soon and how many steps on."""
    live, path = served
    live.moving(1)
    until(
        "cruise", lambda: read_status(path, timeout=READ_DEADLINE_S)["motors"][1]["position"] > 500
    )
    assert live.code(StopMove(1, False)) is None
    assert live.code(WaitMoved(1, 20_000)) is None
    doc = read_status(path, timeout=READ_DEADLINE_S)
    soft = doc["motors"][1]["soft_stops"]
    executor = live.daemon.engine.executor
    config = live.daemon.config  # Move SPEED 1, in step/s (clamped to the motor's maximum)
    speed = min(config.units.run_speed_factor * 1, config.motors[1].max_speed)
    span_s = executor.lead_s + executor.span / 1e9  # type: ignore[attr-defined]
    bound_ms = (span_s + 1 / speed) * 1000
    assert soft["count"] == 1
    assert 0 < soft["takeover_ms"][0] == soft["takeover_ms"][1] <= bound_ms + 1e-6
    # in steps: those planned before the takeover, and those the executor was behind with
    # when the command came (no real-time priority here: up to its worst lateness)
    behind_ms = doc["steps"]["max_us"] / 1000
    assert 0 < soft["takeover_steps"][0] <= (bound_ms + behind_ms) / 1000 * speed + 1


def test_real_time_refused_is_in_the_document_and_in_systemds_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The step thread asks for SCHED_FIFO 50 and the kernel refuses (EPERM, injected at
    os.sched_setscheduler): the document says so, why and the fix; so does STATUS=."""

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    config = '[step_thread]\nexecutor = "thread"\npriority = 50\nlock_memory = false\n'
    live = LiveDaemon(tmp_path, config + TWO_MOTORS, motion=True)
    try:
        doc = live.daemon.status()
    finally:
        live.close()
    rt = doc["executor"]["realtime"]
    assert rt["refused"] == ["sched_fifo"]
    fifo = rt["sched_fifo"]
    assert (fifo["state"], fifo["what"], fifo["error"]) == ("refused", "SCHED_FIFO 50", "EPERM")
    assert fifo["reason"].startswith("EPERM (Operation not permitted)") and fifo["fix"]
    assert rt["memory_lock"]["state"] == "not asked"
    assert summary_line(doc).endswith(
        "; REAL TIME REFUSED (SCHED_FIFO 50): steps best effort, see motorctld --status"
    )


def test_summary_line() -> None:
    status = {
        "motors": [
            {"index": 0, "state": "moving", "fault": None, "position_lost": False},
            {"index": 1, "state": "fault", "fault": "stall", "position_lost": True},
        ],
        "link": {"counters": {"responses": 12, "crc_errors": 1, "sent_E3": 2}},
        "state": {"ok": False, "last_error": "cannot write"},
    }
    assert summary_line(status) == (
        "2 motors: 1 moving, faulted 1, 1 to home; "
        "12 frames served, 3 errors; STATE NOT SAVED: cannot write"
    )
    assert summary_line({"motors": []}) == "0 motors: 0 moving, none faulted"


def test_systemds_status_line_says_the_device_is_gone() -> None:
    link = {"counters": {"responses": 3}, "peer": "gone", "device": "/dev/ttyUSB0"}
    assert (
        summary_line({"motors": [], "link": link})
        == "0 motors: 0 moving, none faulted; 3 frames served, 0 errors; "
        "SERIAL DEVICE /dev/ttyUSB0 GONE, reopening it when it is back"
    )
    link["peer"] = "waiting"
    assert summary_line({"motors": [], "link": link}).endswith(
        "; WAITING FOR SERIAL DEVICE /dev/ttyUSB0 (not there yet)"
    )


def test_the_step_executors_kind_is_asked_of_the_executor_not_its_class() -> None:
    """``executor.kind`` is "none" where no executor times STEP edges, whatever the
    executor's class (a split of ramp chips only, too); the status imports no concrete
    executor (its room knows an executor by the contract of motion/executors/base.py)."""
    from motorctl.daemon.config import parse_config
    from motorctl.daemon.status.document import step_executor_kind
    from motorctl.motion.executors.split import SplitExecutor
    from tests.support import REPO
    from tests.support.executors import RampRig, RecordingExecutor

    config = parse_config('[step_thread]\nexecutor = "thread"\n[[motors]]\n', "test")
    rig = RampRig()
    assert step_executor_kind(config, rig.ex) == "none"
    assert step_executor_kind(config, SplitExecutor([(rig.ex, 0)])) == "none"
    both = SplitExecutor([(rig.ex, 0), (RecordingExecutor(1), 0)])
    assert step_executor_kind(config, both) == "thread"
    rig.ex.close()
    for path in sorted((REPO / "daemon" / "status").glob("*.py")):
        source = path.read_text(encoding="utf-8")
        assert "motorctl.motion.executors." not in source.replace(
            "motorctl.motion.executors.base", ""
        ), path.name
