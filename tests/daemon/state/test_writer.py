"""The state writer (daemon/state/writer.py) on its own, with a scripted snapshot: a write
asked for is done on its thread, a synchronous one at once; a failure is counted, logged
once and said to the status line (``on_change``) when health changes, both ways; the
journal's bytes of motors at rest are cleared only after a durable write; ``close`` writes
the final state. (The writer inside a daemon: tests/daemon/state/test_persistence.py.)"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

import pytest

from motorctl.daemon.state import writer as writer_module
from motorctl.daemon.state.journal import MotionJournal
from motorctl.daemon.state.records import SavedMotor, SavedState
from motorctl.daemon.state.writer import Snapshot, StateWriter
from tests.support.wait import until


class Motors:
    """The snapshot's source: one motor whose position the test sets."""

    def __init__(self, journal: MotionJournal | None = None) -> None:
        self.position = 0
        self.journal = journal
        self.taken = threading.Event()

    def snapshot(self) -> Snapshot:
        self.taken.set()
        motor = SavedMotor("a", "f" * 16, self.position, 0, [], False, False)
        at_rest = {} if self.journal is None else {0: self.journal.token(0)}
        return Snapshot(SavedState([motor]), at_rest)


def on_disk(path: Path) -> int:
    position = json.loads(path.read_text())["motors"][0]["position"]
    assert isinstance(position, int)
    return position


def test_a_requested_write_is_done_on_its_thread_and_close_writes_the_last(
    tmp_path: Path,
) -> None:
    motors = Motors()
    w = StateWriter(tmp_path / "state.json", motors.snapshot)
    w.start()
    motors.position = 7
    w.request()
    until("the requested write", lambda: w.writes == 1)
    assert on_disk(tmp_path / "state.json") == 7 and not w.pending
    motors.position = 9
    assert w.close()  # the final state, written after the thread stopped
    assert on_disk(tmp_path / "state.json") == 9
    status = w.status()
    assert (status["writes"], status["errors"], status["ok"]) == (2, 0, True)
    assert "journal" not in status


def test_a_failure_is_counted_logged_once_and_told_both_ways(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    changes: list[bool] = []
    motors = Motors()
    w = StateWriter(tmp_path / "state.json", motors.snapshot)
    w.on_change = lambda: changes.append(w.healthy)

    def full(path: Path, data: bytes, mode: int = 0o640) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer_module, "write_atomic", full)
    caplog.set_level(logging.INFO, "motorctl.state")
    assert not w.write_now() and not w.write_now()
    assert (w.errors, w.writes, w.healthy) == (2, 0, False)
    assert w.last_error == f"cannot write state file {w.path}: No space left on device"
    assert [r.getMessage() for r in caplog.records] == [w.last_error]  # once
    monkeypatch.undo()
    assert w.write_now()
    assert changes == [False, True]  # the STATUS= line hears of each change, once
    assert caplog.records[-1].getMessage() == f"state file {w.path} written again"
    assert w.status()["last_error"] == w.last_error  # kept for the status


def test_the_journal_of_a_motor_at_rest_is_cleared_after_a_durable_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    journal = MotionJournal(tmp_path / "state.moving", 1)
    journal.reset()
    journal.begin(0)
    journal.end(0)
    motors = Motors(journal)
    w = StateWriter(tmp_path / "state.json", motors.snapshot, journal)

    def fails(path: Path, data: bytes, mode: int = 0o640) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(writer_module, "write_atomic", fails)
    assert not w.write_now()
    assert journal.flagged() == [True]  # not durable: the mark stays
    monkeypatch.undo()
    assert w.write_now()
    assert journal.flagged() == [False]
    assert (tmp_path / "state.moving").read_bytes() == b"0"
    assert w.status()["journal"]["marks"] == 1
    assert w.close()  # closes the journal too
