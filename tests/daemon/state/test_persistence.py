"""Persistence in a daemon built in-process (daemon/state/persistence.py): bad state files
of every kind, config changes, whatever stands in a file's way, the motion journal from a
command's ACK to a restart, a read-only directory, ACK-after-write of saves, fuzzed files.
The state wing's modules on their own: test_records.py, test_files.py, test_journal.py,
test_writer.py beside this file."""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Any

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as hst

from motorctl.daemon.config import ConfigError, parse_config
from motorctl.daemon.start.assemble import Daemon
from motorctl.daemon.state import files, writer
from motorctl.daemon.state import records as st
from motorctl.daemon.state.journal import MotionJournal
from motorctl.daemon.state.persistence import Persistence
from motorctl.daemon.state.records import StateError, parse_state, read_state
from motorctl.protocol.codec import (
    POS_MAX,
    POS_MIN,
    Command,
    ErrorCode,
    GoHome,
    InitMove,
    Move,
    MoveTo,
    MoveToWayPoint,
    Response,
    SaveHome,
    SaveWayPoint,
)
from tests.support.fsutil import read_only
from tests.support.inprocess import build_daemon

E = ErrorCode

CONFIG = """
[[motors]]
name = "a"
max_speed = 3000.0
max_waypoints = 3
[[motors]]
name = "b"
max_speed = 3000.0
"""
ROTARY = CONFIG.replace('name = "b"', 'name = "b"\nsteps_per_rev = 400')


def build(tmp_path: Path, config: str = CONFIG) -> Daemon:
    return build_daemon(config, tmp_path)


def move(d: Daemon, motor: int, pos: int) -> None:
    assert d.dispatcher.handle(MoveTo(motor, True, pos, 0, 0, 0)).ack
    d.engine.run_until_idle()


def saved(tmp_path: Path) -> dict[str, Any]:
    data = json.loads((tmp_path / "state.json").read_text())
    assert isinstance(data, dict)
    return data


def lost(d: Daemon) -> list[bool]:
    return [m.position_lost for m in d.engine.motors]


def good_state(tmp_path: Path) -> dict[str, Any]:
    """A state file written by a daemon: motor a at 120 with home 7 and one waypoint."""
    d = build(tmp_path)
    move(d, 0, 7)
    assert d.dispatcher.handle(SaveHome(0)).ack
    move(d, 0, 120)
    assert d.dispatcher.handle(SaveWayPoint(0)).ack
    d.persistence.close()
    return saved(tmp_path)


# -- a good file round-trips ---------------------------------------------------------------
def test_restore_by_name(tmp_path: Path) -> None:
    good_state(tmp_path)
    d = build(tmp_path)
    a = d.engine.motors[0]
    assert (a.position, a.home, a.waypoints) == (120, 7, [120])
    assert lost(d) == [False, False]
    assert "restored 2 motors" in d.persistence.status()["restored"]
    assert not (tmp_path / "state.json.bad").exists()


def test_fresh_start_has_nothing_to_restore(tmp_path: Path) -> None:
    d = build(tmp_path)
    assert lost(d) == [False, False]
    assert d.persistence.restored == "nothing to restore"
    assert saved(tmp_path)["version"] == st.STATE_VERSION  # written at once


# -- every kind of unreadable file: moved aside, every motor must be homed ------------------
BAD: dict[str, bytes] = {
    "bad bytes": b'{"version": 2, "motors": []}\xff\xfe',
    "bad json": b'{"version": 2, "motors": [',
    "not an object": b"[1, 2]",
    "old version": b'{"version": 1, "motors": []}',
    "motors not a list": b'{"version": 2, "motors": {}}',
    # issue 22: what Python's JSON parser itself refuses crashed every start (traceback)
    "nested 200,000 deep": b"[" * 200_000,
    "an integer of 5,000 digits": b'{"version": 2, "motors": [], "n": ' + b"7" * 5000 + b"}",
    "a version of 5,000 digits": b'{"version": ' + b"7" * 5000 + b', "motors": []}',
    "a version nested 900 deep": b'{"version": ' + b"[" * 900 + b"]" * 900 + b', "motors": []}',
}


def _mutated(tmp_path: Path, key: str, value: Any) -> bytes:
    data = good_state(tmp_path)
    data["motors"][0][key] = value
    return json.dumps(data).encode()


@pytest.mark.parametrize("kind", sorted(BAD))
def test_unreadable_file_is_set_aside(
    tmp_path: Path, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    (tmp_path / "state.json").write_bytes(BAD[kind])
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert (tmp_path / "state.json.bad").read_bytes() == BAD[kind]
    lines = [r.getMessage() for r in caplog.records if "state.json" in r.getMessage()]
    assert len(lines) == 1, lines
    assert "every motor must be homed again" in lines[0] and "kept it as" in lines[0]
    assert len(lines[0]) < 500  # a line, whatever the file holds
    assert d.dispatcher.handle(MoveTo(0, True, 5, 0, 0, 0)).error_code is E.MOTOR_ERROR
    assert saved(tmp_path)["motors"][0]["position_lost"] is True


def two_motors_state(tmp_path: Path) -> dict[str, Any]:
    """A state file written by a daemon: motor a at 120 (home 7, one waypoint), b at -55."""
    good_state(tmp_path)
    d = build(tmp_path)
    move(d, 1, -55)
    d.persistence.close()
    data = saved(tmp_path)
    assert data["motors"][0]["waypoints"] == [120]
    return data


def restored_b(d: Daemon) -> None:
    b = d.engine.motors[1]
    assert (b.position, b.position_lost) == (-55, False)


@pytest.mark.parametrize(
    ("key", "value", "says"),
    [
        ("position", "abc", "not an integer"),
        ("position", True, "not an integer"),
        ("position", 99_999_999, "outside"),
        ("home", -(1 << 23) - 1, "outside"),
        ("waypoints", "x", "not a list"),
        ("waypoints", [1, "2"], "not an integer"),
        ("waypoints", list(range(256)), "the table holds 255"),
        ("moving", "no", "not true or false"),
        ("name", 3, "not a string"),
    ],
)
def test_one_bad_record_loses_only_its_motor(
    tmp_path: Path, key: str, value: Any, says: str, caplog: pytest.LogCaptureFixture
) -> None:
    # PROTOCOL.md §4: an inconsistent file "restores nothing for the motors concerned".
    data = two_motors_state(tmp_path)
    data["motors"][0][key] = value
    bad = json.dumps(data).encode()
    (tmp_path / "state.json").write_bytes(bad)
    d = build(tmp_path)
    assert lost(d) == [True, False]
    restored_b(d)
    assert says in caplog.text
    assert (tmp_path / "state.json.bad").read_bytes() == bad
    assert d.engine.motors[0].waypoints == [] and d.engine.motors[0].home == 0
    assert "restored 1 of 2 motors" in d.persistence.restored
    assert d.dispatcher.handle(MoveTo(0, True, 5, 0, 0, 0)).error_code is E.MOTOR_ERROR
    assert saved(tmp_path)["motors"][0]["position_lost"] is True
    assert saved(tmp_path)["motors"][1]["position"] == -55


def test_a_motor_the_config_does_not_have_keeps_the_file_aside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = two_motors_state(tmp_path)
    q = dict(data["motors"][1], name="q", position=4444)
    data["motors"].insert(1, q)
    text = json.dumps(data).encode()
    (tmp_path / "state.json").write_bytes(text)
    (tmp_path / st.JOURNAL_NAME).write_bytes(b"010")  # q was moving: b is not affected
    d = build(tmp_path)
    assert lost(d) == [False, False]
    assert d.engine.motors[0].position == 120
    restored_b(d)
    assert "has motor 'q', which the config does not have" in caplog.text
    assert (tmp_path / "state.json.bad").read_bytes() == text  # not silently rewritten away
    assert "1 record for no configured motor" in d.persistence.restored
    assert [m["name"] for m in saved(tmp_path)["motors"]] == ["a", "b"]


def test_records_shared_by_two_motors_or_without_a_name(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = two_motors_state(tmp_path)
    data["motors"] += [dict(data["motors"][0], position=9), 3]
    (tmp_path / "state.json").write_text(json.dumps(data))
    d = build(tmp_path)
    assert lost(d) == [True, False]  # which of the two records of "a" is right? neither
    restored_b(d)
    assert "2 motor records are named 'a'" in caplog.text
    assert "motors[3] of no configured motor (motors[3] is not an object)" in caplog.text
    assert (tmp_path / "state.json.bad").exists()


# -- whatever stands in the way is set aside under a free name ----------------------------------
def _make(path: Path, kind: str) -> None:
    """Put a ``kind`` of thing at ``path``. A FIFO's other ends are opened and closed once
    after FIFO_RESCUE_S, should anything be stuck opening it (so that a daemon that opens
    it fails the test instead of hanging it)."""
    if kind == "directory":
        path.mkdir()
        (path / "junk").write_text("x")
    elif kind == "link to a directory":
        (path.parent / "elsewhere").mkdir()
        path.symlink_to(path.parent / "elsewhere")
    elif kind == "link loop":
        path.symlink_to(path)
    elif kind == "dangling link":
        path.symlink_to(path.parent / "missing" / "file")
    elif kind == "fifo":
        os.mkfifo(path)  # reading it would block the start for ever
        rescue = threading.Timer(FIFO_RESCUE_S, _unblock_fifo, [path])
        rescue.daemon = True
        rescue.start()
    else:
        raise AssertionError(kind)


FIFO_RESCUE_S = 10.0


def _unblock_fifo(path: Path) -> None:
    """Open the FIFO's other ends once: a reader or a writer stuck opening it goes on (and
    then fails or reads nothing), instead of waiting for ever."""
    with contextlib.suppress(OSError):
        os.close(os.open(path, os.O_RDONLY | os.O_NONBLOCK))
    with contextlib.suppress(OSError):  # ENXIO: nobody reads it
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))


IN_THE_WAY = ["directory", "link to a directory", "link loop", "dangling link", "fifo"]


@pytest.mark.parametrize("kind", IN_THE_WAY)
def test_whatever_stands_at_the_state_file_is_set_aside_and_the_daemon_runs(
    tmp_path: Path, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    (tmp_path / "state.json.bad").write_text("an older bad file")  # kept, never replaced
    (tmp_path / "state.json.bad.1").mkdir()
    _make(tmp_path / "state.json", kind)
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert "kept it as" in caplog.text and "state.json.bad.2" in caplog.text
    assert (tmp_path / "state.json.bad").read_text() == "an older bad file"
    assert (tmp_path / "state.json.bad.1").is_dir()
    assert os.path.lexists(tmp_path / "state.json.bad.2")
    assert saved(tmp_path)["version"] == st.STATE_VERSION  # state is written again
    # A lost motor can be homed, so the journal works; an unknown waypoint is E6.
    assert d.dispatcher.handle(InitMove(0, False, 0, 0, 0)).ack
    assert d.dispatcher.handle(MoveToWayPoint(1, 0, 0, 0, 0)).error_code is E.INVALID_WAYPOINT
    d.engine.run_until_idle()
    assert lost(d) == [False, True]
    assert d.persistence.close()


def test_directory_in_place_of_the_file(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "state.json").mkdir()
    (tmp_path / "state.json" / "junk").write_text("x")
    (tmp_path / "state.json.bad").mkdir()  # an older one, also a directory: kept
    (tmp_path / "state.json.bad" / "old").write_text("y")
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert "is a directory" in caplog.text
    assert (tmp_path / "state.json.bad.1" / "junk").exists()
    assert (tmp_path / "state.json.bad" / "old").exists()
    assert saved(tmp_path)["version"] == st.STATE_VERSION


@pytest.mark.parametrize("kind", IN_THE_WAY)
def test_whatever_stands_at_the_temporary_file_is_set_aside(tmp_path: Path, kind: str) -> None:
    d = build(tmp_path)
    move(d, 0, 12)
    _make(tmp_path / "state.json.tmp", kind)
    assert d.writer.write_now()
    assert saved(tmp_path)["motors"][0]["position"] == 12
    assert os.path.lexists(tmp_path / "state.json.tmp.bad")
    assert not os.path.lexists(tmp_path / "state.json.tmp")
    assert not (tmp_path / "missing").exists()  # a link was not written through


def test_a_directory_made_at_the_state_file_while_running(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    d = build(tmp_path)
    move(d, 0, 12)
    (tmp_path / "state.json").unlink()
    (tmp_path / "state.json").mkdir()
    assert d.writer.write_now()
    assert saved(tmp_path)["motors"][0]["position"] == 12
    assert (tmp_path / "state.json.bad").is_dir()
    assert f"{tmp_path / 'state.json'} was a directory" in caplog.text


@pytest.mark.parametrize("kind", IN_THE_WAY)
def test_whatever_stands_at_the_journal_is_set_aside(tmp_path: Path, kind: str) -> None:
    good_state(tmp_path)
    (tmp_path / st.JOURNAL_NAME).unlink()
    _make(tmp_path / st.JOURNAL_NAME, kind)
    d = build(tmp_path)
    assert lost(d) == [True, True]  # the journal could not be read: every motor moved
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"
    assert os.path.lexists(tmp_path / (st.JOURNAL_NAME + ".bad"))
    assert d.dispatcher.handle(InitMove(0, False, 0, 0, 0)).ack


def test_no_free_name_left(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(files, "ASIDE_LIMIT", 3)
    for name in ("state.json", "state.json.bad", "state.json.bad.1", "state.json.bad.2"):
        (tmp_path / name).mkdir()
    assert files.set_aside(tmp_path / "state.json") is None
    assert "are all taken; remove old ones" in caplog.text


def test_unreadable_state_file(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    path.symlink_to(path)
    with pytest.raises(StateError, match="is a symbolic link, not a regular file"):
        read_state(path)
    path.unlink()
    path.write_text("{}")
    if os.geteuid() != 0:  # root reads any file
        path.chmod(0)
        with pytest.raises(StateError, match="cannot be read"):
            read_state(path)


# -- files for another config: restore nothing for the motors that changed --------------------
def test_swapped_names_restore_by_name(tmp_path: Path) -> None:
    good_state(tmp_path)
    swapped = CONFIG.replace('"a"', '"tmp"').replace('"b"', '"a"').replace('"tmp"', '"b"')
    d = build(tmp_path, swapped.replace("max_waypoints = 3", "max_waypoints = 5"))
    b, a = d.engine.motors
    assert (a.params.name, a.position, a.home, a.waypoints) == ("a", 120, 7, [120])
    assert b.position == 0 and not b.position_lost


def test_renamed_or_changed_geometry(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    good_state(tmp_path)
    caplog.set_level(logging.WARNING)
    d = build(tmp_path, ROTARY.replace('"a"', '"x"'))
    assert lost(d) == [True, True]
    assert "motor 0 (x): nothing restored" in caplog.text
    assert "not in the state file" in caplog.text
    assert "motor 1 (b): nothing restored" in caplog.text
    assert "geometry changed" in caplog.text
    assert (tmp_path / "state.json.bad").exists()
    assert "restored 0 of 2" in d.persistence.restored


def test_more_waypoints_than_the_configured_table(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = good_state(tmp_path)
    data["motors"][0]["waypoints"] = [1, 2, 3, 4]
    (tmp_path / "state.json").write_text(json.dumps(data))
    d = build(tmp_path)
    assert lost(d) == [True, False]
    assert "4 waypoints saved, its table holds 3" in caplog.text
    assert d.engine.motors[0].waypoints == []


def test_rotary_position_outside_its_revolution(tmp_path: Path) -> None:
    build(tmp_path, ROTARY).persistence.close()
    data = saved(tmp_path)
    data["motors"][1]["position"] = 400
    (tmp_path / "state.json").write_text(json.dumps(data))
    d = build(tmp_path, ROTARY)
    assert lost(d) == [False, True]


# -- moving when the daemon died -----------------------------------------------------------------
def test_saved_moving_means_lost_but_home_and_waypoints_kept(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = good_state(tmp_path)
    data["motors"][0]["moving"] = True
    (tmp_path / "state.json").write_text(json.dumps(data))
    d = build(tmp_path)
    a = d.engine.motors[0]
    assert a.position_lost and a.home == 7 and a.waypoints == [120]
    assert "motor 0 (a) was moving when the daemon stopped" in caplog.text


def test_journal_marks_moving_before_the_ack(tmp_path: Path) -> None:
    d = build(tmp_path)
    journal = tmp_path / st.JOURNAL_NAME
    assert journal.read_bytes() == b"00"
    assert d.dispatcher.handle(MoveTo(1, True, 500, 0, 0, 0)).ack
    # A SIGKILL now: state.json still says "at rest at 0", the journal says moving.
    assert journal.read_bytes() == b"01"
    assert saved(tmp_path)["motors"][1]["moving"] is False
    d2 = build(tmp_path)  # what a restart would see
    assert lost(d2) == [False, True]


def test_journal_cleared_once_at_rest_is_durable(tmp_path: Path) -> None:
    d = build(tmp_path)
    move(d, 1, 500)
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"01"
    assert d.writer.write_now()  # what the writer thread does on the idle event
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"
    d2 = build(tmp_path)
    assert lost(d2) == [False, False]
    assert d2.engine.motors[1].position == 500


def test_a_rejected_motion_leaves_no_mark(tmp_path: Path) -> None:
    d = build(tmp_path)
    d.engine.motors[0].fault = "test"
    assert d.dispatcher.handle(MoveTo(0, True, 5, 0, 0, 0)).error_code is E.MOTOR_ERROR
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"  # at once, without a write
    assert d.persistence.status()["journal"]["withdrawn"] == 1


@pytest.mark.parametrize("command", ["MoveTo", "GoHome", "MoveToWayPoint", "rotary MoveTo"])
def test_a_motion_of_no_distance_leaves_no_mark(tmp_path: Path, command: str) -> None:
    # Issue 16: a MoveTo to where the motor stands left its journal byte set until the
    # writer's next durable write; a kill -9 meanwhile brought the idle motor back lost.
    d = build(tmp_path, ROTARY)
    move(d, 1, 250)
    assert d.dispatcher.handle(SaveHome(1)).ack
    assert d.dispatcher.handle(SaveWayPoint(1)).ack
    assert d.writer.write_now()
    journal = tmp_path / st.JOURNAL_NAME
    assert journal.read_bytes() == b"00"
    commands: dict[str, Command] = {
        "MoveTo": MoveTo(1, True, 250, 0, 0, 0),
        "GoHome": GoHome(1),
        "MoveToWayPoint": MoveToWayPoint(1, 0, 0, 0, 0),
        "rotary MoveTo": MoveTo(1, False, 250 + 400, 0, 0, 0),
    }
    cmd = commands[command]
    assert d.dispatcher.handle(cmd).ack
    assert d.engine.motors[1].idle
    assert journal.read_bytes() == b"00"  # a kill -9 now: the motor is where the disk says
    d2 = build(tmp_path, ROTARY)  # what a restart after a kill -9 sees
    assert lost(d2) == [False, False]
    assert d2.engine.motors[1].position == 250


def test_a_motion_that_moves_keeps_its_mark(tmp_path: Path) -> None:
    d = build(tmp_path)
    move(d, 1, 250)
    assert d.writer.write_now()
    assert d.dispatcher.handle(MoveTo(1, True, 251, 0, 0, 0)).ack
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"01"
    assert d.persistence.status()["journal"]["withdrawn"] == 0
    d.engine.run_until_idle()
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"01"  # until the state is durable
    assert d.writer.write_now()
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"


def test_journal_unreadable_or_missing_state(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    good_state(tmp_path)
    (tmp_path / st.JOURNAL_NAME).write_bytes(b"zz")
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert "motion journal" in caplog.text and "unreadable" in caplog.text
    (tmp_path / "state.json").unlink()
    (tmp_path / st.JOURNAL_NAME).write_bytes(b"01")
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert MotionJournal.read(tmp_path / "nothing") == []
    (tmp_path / "dir").mkdir()
    with pytest.raises(StateError, match="is a directory"):
        MotionJournal.read(tmp_path / "dir")


def test_journal_not_open_refuses_motion(tmp_path: Path) -> None:
    d = build(tmp_path)
    d.persistence.journal.close()
    r = d.dispatcher.handle(MoveTo(0, True, 5, 0, 0, 0))
    assert r.error_code is E.MOTOR_ERROR
    assert d.persistence.status()["motion_refused"] == 1
    assert d.engine.motors[0].idle


def test_a_motion_that_cannot_be_recorded_is_e4_in_its_place(tmp_path: Path) -> None:
    # PROTOCOL.md §5: E1 -> E2 -> E1 (parameters) -> E6 -> E4; the journal's failure is an
    # E4 and takes E4's place (it used to come before every check of the command).
    d = build(
        tmp_path,
        CONFIG.replace('name = "b"', 'name = "b"\nsoft_limit_min = -10\nsoft_limit_max = 10'),
    )
    d.persistence.journal.close()
    handle = d.dispatcher.handle
    assert handle(MoveToWayPoint(0, 0, 0, 0, 0)).error_code is E.INVALID_WAYPOINT
    assert handle(MoveTo(5, True, 1, 0, 0, 0)).error_code is E.INVALID_ADDRESS
    assert handle(MoveTo(1, True, 11, 0, 0, 0)).error_code is E.INVALID_COMMAND
    for cmd in (
        MoveTo(1, True, 5, 0, 0, 0),
        InitMove(0, False, 0, 0, 0),
        GoHome(1),
        Move(0, True, 1, 0, 0),
    ):
        assert handle(cmd).error_code is E.MOTOR_ERROR, cmd
    assert all(m.idle for m in d.engine.motors)
    assert d.persistence.status()["motion_refused"] == 6  # all but the unknown motor


# -- writes: complete or absent ------------------------------------------------------------------


def test_read_only_directory_save_answers_e4(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    d = build(tmp_path)
    move(d, 0, 40)
    before = saved(tmp_path)
    with read_only(tmp_path):
        r = d.dispatcher.handle(SaveWayPoint(0))
        assert r.error_code is E.MOTOR_ERROR
        assert d.engine.motors[0].waypoints == []  # undone: the host was not told "saved"
        assert d.dispatcher.handle(SaveHome(0)).error_code is E.MOTOR_ERROR
        assert d.engine.motors[0].home == 0
        status = d.persistence.status()
        assert status["ok"] is False and status["save_errors"] == 2
        assert "cannot write state file" in status["last_error"]
        assert not d.persistence.close()  # the final write fails without a traceback
    assert saved(tmp_path) == before
    assert caplog.text.count("cannot write state file") == 1  # logged once, not per write
    assert (
        "motor 0 (a): SaveWayPoint(motor=0) answered E4 Motor Error: not saved: the state "
        "file cannot be written" in caplog.text
    )
    rec = next(r for r in caplog.records if "SaveHome(motor=0) answered E4" in r.getMessage())
    assert (rec.MOTOR, rec.COMMAND, rec.ERROR_CODE) == (0, "SaveHome", "E4")  # type: ignore[attr-defined]
    assert d.writer.write_now()
    assert d.persistence.status()["ok"] is True
    assert "written again" in caplog.text


def test_save_acks_only_after_the_write(tmp_path: Path) -> None:
    d = build(tmp_path)
    move(d, 0, 33)
    r = d.dispatcher.handle(SaveWayPoint(0))
    assert r == Response.ok(bytes([0]))
    assert saved(tmp_path)["motors"][0]["waypoints"] == [33]  # on disk when the ACK leaves
    assert d.dispatcher.handle(SaveHome(0)).ack
    assert saved(tmp_path)["motors"][0]["home"] == 33


def test_writer_thread_and_status(tmp_path: Path) -> None:
    d = build(tmp_path)
    d.persistence.start()
    move(d, 0, 10)  # the idle event requests a write from the thread
    d.persistence.close()
    s = d.persistence.status()
    assert s["writes"] >= 2 and s["errors"] == 0 and s["journal"]["marks"] == 1
    assert s["journal"]["mean_mark_us"] > 0
    assert saved(tmp_path)["motors"][0]["position"] == 10


def test_open_with_unwritable_journal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    d = build(tmp_path)
    d.persistence.close()
    journal = str(tmp_path / st.JOURNAL_NAME)
    real = os.open

    def refuse(path: Any, flags: int, mode: int = 0o777, **kw: Any) -> int:
        if str(path) == journal:
            raise OSError(errno.EIO, "Input/output error")
        return real(path, flags, mode, **kw)

    monkeypatch.setattr(os, "open", refuse)
    d = build(tmp_path)
    assert "cannot start the motion journal" in caplog.text
    assert d.dispatcher.handle(MoveTo(0, True, 5, 0, 0, 0)).error_code is E.MOTOR_ERROR


def test_identities_must_match_motors(tmp_path: Path) -> None:
    d = build(tmp_path)
    with pytest.raises(ValueError):
        Persistence(tmp_path, [], d.engine)


def test_state_directory_option(tmp_path: Path) -> None:
    elsewhere = tmp_path / "var-lib"
    config = f'[state]\ndirectory = "{elsewhere}"\n' + CONFIG
    d = build(tmp_path / "run", config)
    move(d, 0, 9)
    d.persistence.close()
    assert json.loads((elsewhere / "state.json").read_text())["motors"][0]["position"] == 9
    assert not (tmp_path / "run" / "state.json").exists()
    with pytest.raises(ConfigError, match="absolute path"):
        parse_config('[state]\ndirectory = "relative"\n' + CONFIG, "t.toml")


# -- a bounded read (issue 22) -------------------------------------------------------------------


def test_a_state_file_over_the_bound_is_set_aside_unread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # Issue 22: a 100 MB padded file took 1.2 s and 129 MB to be accepted.
    path = tmp_path / "state.json"
    with open(path, "wb") as f:
        f.truncate(100 << 20)  # sparse: nothing to write, a lot to read
    real_read = os.read

    def no_read(fd: int, n: int) -> bytes:
        raise AssertionError("a file over the bound was read")

    monkeypatch.setattr(os, "read", no_read)
    with pytest.raises(StateError, match=f"{path} has {100 << 20} bytes, more than the 4 MiB"):
        read_state(path)
    monkeypatch.setattr(os, "read", real_read)
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert (tmp_path / "state.json.bad").stat().st_size == 100 << 20
    lines = [r.getMessage() for r in caplog.records if str(path) in r.getMessage()]
    assert len(lines) == 1 and "kept it as" in lines[0]


def test_a_state_file_at_the_bound_is_read(tmp_path: Path) -> None:
    data = json.dumps(two_motors_state(tmp_path)).encode()
    (tmp_path / "state.json").write_bytes(data + b" " * (st.MAX_FILE_BYTES - len(data)))
    d = build(tmp_path)
    restored_b(d)
    assert d.persistence.restored == "restored 2 motors"


# -- a journal that cannot be read: set aside once the state file is durable --------------------
@pytest.mark.parametrize(
    "content",
    [b"zz", b"0" * (st.MAX_FILE_BYTES + 1), b"01\n", b"\x00"],
    ids=["letters", "over the bound", "a line end", "a NUL"],
)
def test_an_unreadable_journal_is_set_aside_with_one_line(
    tmp_path: Path, content: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    good_state(tmp_path)
    (tmp_path / st.JOURNAL_NAME).write_bytes(content)
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert (tmp_path / (st.JOURNAL_NAME + ".bad")).read_bytes() == content
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"00"
    lines = [r.getMessage() for r in caplog.records if "motion journal" in r.getMessage()]
    assert len(lines) == 1 and "every motor counts as moved; kept it as" in lines[0], lines
    assert len(lines[0]) < 500


def test_an_unreadable_journal_stays_while_the_state_cannot_be_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """The journal is all that says a motor was moving: it is kept in place until a state
    file that says so (every motor lost) is durable, so that a restart still sees it."""
    good_state(tmp_path)
    (tmp_path / st.JOURNAL_NAME).write_bytes(b"zz")

    def cannot(path: Path, data: bytes, mode: int = 0o640) -> None:
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(writer, "write_atomic", cannot)
    d = build(tmp_path)
    assert lost(d) == [True, True]
    assert (tmp_path / st.JOURNAL_NAME).read_bytes() == b"zz"
    assert "every motor counts as moved; it stays where it is" in caplog.text
    monkeypatch.undo()
    d = build(tmp_path)  # the next start: still every motor lost, and now set aside
    assert lost(d) == [True, True]
    assert (tmp_path / (st.JOURNAL_NAME + ".bad")).read_bytes() == b"zz"


# -- fuzzing: anything at all in the files is a clear "not restored", never an exception ---------
JSON = hst.recursive(
    hst.none()
    | hst.booleans()
    | hst.integers()
    | hst.integers(min_value=-(10**80), max_value=10**80)
    | hst.floats(allow_nan=True, allow_infinity=True)
    | hst.text(max_size=20),
    lambda inner: hst.lists(inner, max_size=4) | hst.dictionaries(hst.text(max_size=8), inner),
    max_leaves=20,
)
RECORD_KEYS = ["name", "fingerprint", "position", "home", "waypoints", "moving", "position_lost"]


def _document(valid: dict[str, Any], changes: list[tuple[int, str, Any]], extra: Any) -> bytes:
    doc = json.loads(json.dumps(valid))
    for index, key, value in changes:
        if index < len(doc["motors"]):
            doc["motors"][index][key] = value
        else:
            doc["motors"].append({key: value})
    doc["mock"] = extra
    return json.dumps(doc).encode()


POISON = [
    b"[" * 200_000,
    b"{" * 200_000,
    b'{"version": 2, "motors": [], "n": ' + b"9" * 5000 + b"}",
    b'{"version": 2, "motors": [' + b'{"name": "a"},' * 3 + b"1e999]}",
    b'{"version": 2, "motors": [{"name": "\\ud800"}]}',
    b'{"version": 2, "motors": [], "mock": {"axes": 5}}',
    b'{"version": 2, "motors": [], "mock": {"axes": [1e300, true, 99999999999999999999999]}}',
    b'\xef\xbb\xbf{"version": 2, "motors": []}',
    b"\x00" * 64,
]


@settings(max_examples=100, deadline=None)
@given(raw=hst.binary(max_size=500) | JSON.map(lambda v: json.dumps(v).encode()))
@example(raw=POISON[0])
@example(raw=POISON[2])
def test_parse_state_takes_any_bytes(raw: bytes) -> None:
    try:
        state = parse_state(raw)
    except StateError as exc:
        assert len(str(exc)) < 500
        return
    for motor in state.motors:
        assert isinstance(motor.position, int) and POS_MIN <= motor.position <= POS_MAX
    assert all(len(b.problem) < 500 for b in state.bad)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def valid_state(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A state file of two motors as a daemon writes it (a and b restored, see
    two_motors_state), for the fuzzer to spoil."""
    return two_motors_state(tmp_path_factory.mktemp("valid"))


def test_the_fuzzers_document_restores_when_unspoilt(
    tmp_path: Path, valid_state: dict[str, Any]
) -> None:
    (tmp_path / "state.json").write_bytes(_document(valid_state, [], {"axes": [3, 4]}))
    d = build(tmp_path)
    assert d.persistence.restored == "restored 2 motors"
    restored_b(d)


@settings(max_examples=60, deadline=None)
@given(
    state=hst.one_of(
        hst.none(),
        hst.sampled_from(POISON),
        hst.binary(max_size=200),
        hst.tuples(
            hst.lists(
                hst.tuples(hst.integers(0, 3), hst.sampled_from(RECORD_KEYS), JSON), max_size=3
            ),
            JSON | hst.fixed_dictionaries({"axes": JSON}),
        ),
    ),
    journal=hst.none() | hst.binary(max_size=6) | hst.sampled_from([b"00", b"11", b"10"]),
)
@example(state=([], {"axes": 5}), journal=None)  # every motor restored: the mock's turn
@example(state=([], {"axes": [10**30, True, 1.5, None]}), journal=b"00")
def test_anything_in_the_state_and_journal_files_starts_the_daemon(
    fuzz_dir: Path, valid_state: dict[str, Any], state: Any, journal: bytes | None
) -> None:
    """Whatever the two files hold: the daemon is built (no exception), a state file of its
    own is written, and a file that was not wholly restored is kept aside."""
    folder = Path(tempfile.mkdtemp(dir=fuzz_dir))
    try:
        if isinstance(state, tuple):
            (folder / "state.json").write_bytes(_document(valid_state, *state))
        elif state is not None:
            (folder / "state.json").write_bytes(state)
        if journal is not None:
            (folder / st.JOURNAL_NAME).write_bytes(journal)
        before = (folder / "state.json").read_bytes() if (folder / "state.json").exists() else None
        d = build(folder)
        restored = d.persistence.restored
        assert saved(folder)["version"] == st.STATE_VERSION
        if before is not None and not restored.startswith("restored 2 motors"):
            kept = (folder / "state.json.bad").read_bytes()
            assert kept == before, restored
        assert (folder / st.JOURNAL_NAME).read_bytes() == b"00"
        d.persistence.close()
    finally:
        shutil.rmtree(folder)
