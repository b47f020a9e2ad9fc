"""The motion journal (daemon/state/journal.py) on its own: withdrawing only the start it
was given, the token that protects a start in flight, whatever stands at its path. (The
journal in a daemon, from motion command to restart: tests/daemon/state/test_persistence.py.)"""

from __future__ import annotations

from pathlib import Path

from motorctl.daemon.state import records as st
from motorctl.daemon.state.journal import MotionJournal


def test_withdraw_only_the_start_it_was_given(tmp_path: Path) -> None:
    j = MotionJournal(tmp_path / "j", 1)
    j.reset()
    token = j.begin(0)
    assert token is not None
    assert not j.withdraw(0, token)  # still in flight
    j.end(0)
    assert j.begin(0) is None  # already marked: nothing to withdraw for this one
    j.end(0)
    assert not j.withdraw(0, token)  # another start came since
    assert j.flagged() == [True]
    j.clear_if_unchanged(0, j.token(0))
    token = j.begin(0)
    j.end(0)
    assert token is not None and j.withdraw(0, token)
    assert (tmp_path / "j").read_bytes() == b"0" and j.flagged() == [False]
    assert not j.withdraw(0, token)  # once
    j.close()


def test_journal_token_protects_a_start_in_flight(tmp_path: Path) -> None:
    j = MotionJournal(tmp_path / "j", 1)
    j.reset()
    j.begin(0)
    assert j.token(0) is None  # a snapshot now must not clear
    j.clear_if_unchanged(0, None)
    assert j.flagged() == [True]
    j.end(0)
    token = j.token(0)
    j.begin(0)  # restarted after the snapshot: the old token no longer clears
    j.end(0)
    j.clear_if_unchanged(0, token)
    assert j.flagged() == [True]
    j.clear_if_unchanged(0, j.token(0))
    assert j.flagged() == [False]
    assert j.marks == 1  # the second begin found the flag already durable
    j.close()
    j.clear_if_unchanged(0, j.token(0))


def test_journal_directory_in_its_place(tmp_path: Path) -> None:
    (tmp_path / st.JOURNAL_NAME).mkdir()
    j = MotionJournal(tmp_path / st.JOURNAL_NAME, 2)
    j.reset()
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"
    assert (tmp_path / (st.JOURNAL_NAME + ".bad")).is_dir()
    j.close()
