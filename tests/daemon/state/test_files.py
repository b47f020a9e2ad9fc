"""Whatever stands at a path the daemon writes (daemon/state/files.py), in-process: every kind of
trap (tests/support/traps.py) that another user can place in a shared sticky folder, at
each of the daemon's files (the lock files, state.json and its temporary file, the motion
journal, the status socket, a trace file). Nothing is followed, opened, written through or
waited for; the trap is set aside as it was, logged once, and the daemon's file is made
anew. The same as a process among traps: tests/daemon/state/test_files_e2e.py. And
writes complete or absent: short writes, a write of nothing, a full disk."""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.instance import InstanceError, InstanceLock
from motorctl.daemon.link.recorder import TraceRecorder, rotated
from motorctl.daemon.state import files
from motorctl.daemon.state.files import write_all, write_atomic
from motorctl.daemon.state.journal import MotionJournal
from motorctl.daemon.state.records import JOURNAL_NAME, STATE_NAME, StateError, read_state
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer
from motorctl.protocol.capture.format import CaptureInfo
from tests.support.fsutil import read_only
from tests.support.inprocess import TWO_MOTORS, build_daemon
from tests.support.traps import KINDS, OTHER, VICTIM_TEXT, Trap, place, shared_folder


@pytest.fixture
def shared(tmp_path: Path) -> Path:
    return shared_folder(tmp_path)


@pytest.fixture
def umask() -> Iterator[None]:
    """The service's UMask=0027 while the test runs."""
    old = os.umask(0o027)
    yield
    os.umask(old)


def moved_aside_lines(caplog: pytest.LogCaptureFixture, path: Path) -> list[str]:
    return [r.getMessage() for r in caplog.records if f"{path} was " in r.getMessage()]


def assert_ours(path: Path, mode: int) -> None:
    st = os.lstat(path)
    assert stat.S_ISREG(st.st_mode) and st.st_nlink == 1 and st.st_uid == os.geteuid()
    assert stat.S_IMODE(st.st_mode) == mode


# -- each writer, each kind of trap -------------------------------------------------------------
def write_lock(path: Path) -> None:
    lock = InstanceLock(path, "state directory X")
    lock.acquire()
    assert path.read_text() == f"{os.getpid()}\n"
    assert_ours(path, 0o640)
    lock.release()
    assert not os.path.lexists(path)


def write_state_temp(path: Path) -> None:
    state = path.with_name(STATE_NAME)
    assert path.name == STATE_NAME + ".tmp"
    write_atomic(state, b"{}\n")
    assert state.read_bytes() == b"{}\n"
    assert_ours(state, 0o640)
    assert not os.path.lexists(path)


def write_journal(path: Path) -> None:
    journal = MotionJournal(path, 2)
    journal.reset()
    assert path.read_bytes() == b"00"
    assert_ours(path, 0o640)
    journal.close()


def write_trace(path: Path) -> None:
    info = CaptureInfo(role="daemon", frame_gap_ms=10.0, port="/dev/test")
    rec = TraceRecorder(path, info, max_bytes=1 << 16, files=2, clock_origin=0.0, flush_s=3600)
    rec.open()
    rec.received(b"abc", 0.001)
    rec.close()
    assert_ours(path, 0o640)
    assert path.stat().st_size > 3


def bind_status(path: Path) -> None:
    server = StatusServer(path, lambda histogram=False: {"motors": []})
    try:
        st = os.lstat(path)
        assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o660  # not umasked
        server.start()
        assert read_status(path) == {"motors": []}
    finally:
        server.close()
    assert [p.name for p in path.parent.iterdir() if p.name.startswith(".s")] == []


WRITERS: dict[str, tuple[str, Callable[[Path], None]]] = {
    "lock file": ("motorctld.lock", write_lock),
    "PTY lock file": (".motorctl.pty.lock", write_lock),
    "state temporary file": (STATE_NAME + ".tmp", write_state_temp),
    "motion journal": (JOURNAL_NAME, write_journal),
    "trace file": ("trace.pcapng", write_trace),
    "status socket": ("status.sock", bind_status),
}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_trap_at_a_path_the_daemon_writes_is_set_aside_once(
    shared: Path, writer: str, kind: str, umask: None, caplog: pytest.LogCaptureFixture
) -> None:
    name, write = WRITERS[writer]
    path = shared / name
    trap = place(path, kind)
    if writer == "trace file" and kind == "device":
        with pytest.raises(OSError, match=f"{path} is a character device, not a file"):
            write(path)  # only root makes a device: refused, left where it is
        trap.check(set_aside=False)
        assert stat.S_ISCHR(os.lstat(path).st_mode)
        return
    write(path)
    if writer == "status socket" and kind == "socket":
        # a socket at status.sock is a stale one (the caller holds the instance lock)
        trap.check(set_aside=False)
        assert not os.path.lexists(path.with_name(path.name + ".bad"))
        return
    trap.check()
    lines = moved_aside_lines(caplog, path)
    assert len(lines) == 1, lines
    assert f"moved aside to {path}.bad" in lines[0]


@pytest.mark.parametrize("kind", KINDS)
def test_a_trap_at_the_state_file_is_never_read_through(
    shared: Path, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    path = shared / STATE_NAME
    trap = place(path, kind)
    with pytest.raises(StateError) as info:
        read_state(path)
    assert str(path) in str(info.value)
    trap.check(set_aside=False)
    d = build_daemon(TWO_MOTORS, shared)  # restores: sets it aside, writes a state of its own
    assert all(m.position_lost for m in d.engine.motors)
    trap.check()
    assert_ours(path, 0o640 & ~_umask())
    errors = [r for r in caplog.records if str(path) in r.getMessage()]
    assert len(errors) == 1 and f"kept it as {path}.bad" in errors[0].getMessage()
    d.persistence.close()


def _umask() -> int:
    old = os.umask(0)
    os.umask(old)
    return old


def test_a_trace_to_a_device_is_refused_and_the_device_left_alone(shared: Path) -> None:
    """``--trace /dev/null`` or ``/dev/stdout`` as root: the device (or the link to it) is
    neither written, nor set aside, nor rotated away (renaming /dev/null breaks a system)."""
    device = shared / "null"
    os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    link = shared / "stdout"
    link.symlink_to(device)
    for path, through in ((device, ""), (link, r" \(through a symbolic link\)")):
        with pytest.raises(OSError, match=f"{path} is a character device{through}, not a file"):
            write_trace(path)
    assert sorted(p.name for p in shared.iterdir()) == ["null", "stdout"]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("files", [2, 3], ids=["oldest-name", "middle-name"])
def test_a_trap_at_a_rotated_trace_name_is_set_aside_never_removed_or_moved(
    shared: Path, kind: str, files: int, caplog: pytest.LogCaptureFixture
) -> None:
    """Rotation removes the oldest name (``FILE.1`` of 2 files) and renames the others
    (``FILE.1`` to ``FILE.2`` of 3): only the daemon's own trace files. Another user's
    thing at a rotated name is set aside as it would be at ``FILE`` (never deleted, never
    renamed into the daemon's files, never a start that fails on a folder there)."""
    path = shared / "trace.pcapng"
    write_trace(path)  # the daemon's own FILE, which the next start rotates to FILE.1
    trap = place(rotated(path, 1), kind)
    info = CaptureInfo(role="daemon", frame_gap_ms=10.0, port="/dev/test")
    rec = TraceRecorder(path, info, max_bytes=1 << 16, files=files, clock_origin=0.0)
    rec.open()
    rec.close()
    trap.check()
    assert len(moved_aside_lines(caplog, rotated(path, 1))) == 1
    assert_ours(rotated(path, 1), 0o640 & ~_umask())  # the first run's FILE, rotated
    assert_ours(path, 0o640 & ~_umask())


# -- the daemon's own files are taken as they are -----------------------------------------------
def test_a_file_of_its_own_is_reused_not_set_aside(
    shared: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = shared / "motorctld.lock"
    path.write_text("12345\n")  # a lock file left by a daemon killed with SIGKILL
    ino = path.stat().st_ino
    lock = InstanceLock(path, "X")
    lock.acquire()
    assert path.stat().st_ino == ino and path.read_text() == f"{os.getpid()}\n"
    lock.release()
    # A file of the folder's owner is the daemon's too (a --state-dir owned by its user).
    folder = shared / "theirs"
    folder.mkdir()
    os.chown(folder, OTHER, OTHER)
    (folder / JOURNAL_NAME).write_bytes(b"1")
    os.chown(folder / JOURNAL_NAME, OTHER, OTHER)
    fd = files.open_for_writing(folder / JOURNAL_NAME)
    os.close(fd)
    assert not os.path.lexists(folder / (JOURNAL_NAME + ".bad"))
    assert "was " not in caplog.text


def test_another_users_lock_file_is_another_daemons_while_held(shared: Path) -> None:
    path = shared / ".motorctl.pty.lock"
    trap = place(path, "their file")
    path.write_text("4242\n")
    held = os.open(path, os.O_RDONLY)
    fcntl.flock(held, fcntl.LOCK_EX)  # another user's daemon (or a process) holds it
    try:
        with pytest.raises(InstanceError, match=r"another motorctld \(PID 4242\)"):
            InstanceLock(path, "PTY x").acquire()
        assert os.lstat(path).st_ino == trap.identity[1]  # left alone
    finally:
        os.close(held)
    lock = InstanceLock(path, "PTY x")
    lock.acquire()  # nobody holds it now: set aside, ours made
    trap.check()
    lock.release()


# -- swapped between the look and the open --------------------------------------------------------
@pytest.mark.parametrize("kind", ["fifo", "link", "directory"])
def test_a_file_swapped_after_the_look_is_never_used(
    shared: Path, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The lstat finds a file of ours; before the open, someone swaps in a trap: the open
    (O_NOFOLLOW | O_NONBLOCK) and its fstat catch it, and the trap is set aside."""
    path = shared / JOURNAL_NAME
    path.write_bytes(b"00")
    real_open = os.open
    traps: list[Trap] = []

    def swap_then_open(p: object, flags: int, mode: int = 0o777, **kw: object) -> int:
        if str(p) == str(path) and not traps and not flags & os.O_CREAT:
            path.unlink()
            traps.append(place(path, kind))
        return real_open(p, flags, mode, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "open", swap_then_open)
    fd = files.open_for_writing(path)
    monkeypatch.undo()
    os.close(fd)
    traps[0].check()
    assert_ours(path, 0o640 & ~_umask())


def test_a_path_that_keeps_being_replaced_gives_up(
    shared: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = shared / "motorctld.lock"
    real_open = os.open

    def always_taken(p: object, flags: int, mode: int = 0o777, **kw: object) -> int:
        if str(p) == str(path) and flags & os.O_EXCL:
            raise FileExistsError(errno.EEXIST, "File exists")
        return real_open(p, flags, mode, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "open", always_taken)
    with pytest.raises(OSError, match="keeps being replaced"):
        files.open_for_writing(path)
    with pytest.raises(InstanceError, match=r"cannot create lock file .*keeps being replaced"):
        InstanceLock(path, "X").acquire()


def test_nothing_can_be_set_aside(shared: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = shared / JOURNAL_NAME
    place(path, "fifo").check(set_aside=False)
    monkeypatch.setattr(files, "ASIDE_LIMIT", 0)
    with pytest.raises(OSError, match=r"cannot move .* aside: .*are all taken"):
        files.open_for_writing(path)
    assert stat.S_ISFIFO(os.lstat(path).st_mode)  # left as it was, never opened


# -- the status socket ---------------------------------------------------------------------------
def test_the_status_socket_mode_is_exact_whatever_the_umask(shared: Path) -> None:
    path = shared / "status.sock"
    for mask in (0o077, 0o027, 0o000):
        old = os.umask(mask)
        try:
            sock = files.bind_socket(path, 0o660)
        finally:
            os.umask(old)
        assert stat.S_IMODE(os.lstat(path).st_mode) == 0o660
        sock.close()  # a stale socket stays: the next bind replaces it
    assert sorted(p.name for p in shared.iterdir()) == ["status.sock"]


def test_the_private_folder_is_new_and_its_users_alone(shared: Path) -> None:
    old = os.umask(0o000)
    try:
        made = [files.private_folder(shared) for _ in range(20)]
    finally:
        os.umask(old)
    assert len(set(made)) == 20
    for folder in made:
        assert folder.parent == shared
        assert len(folder.name) == len(".sXXXXXXXX") and folder.name.startswith(".s")
        st = os.lstat(folder)
        assert stat.S_ISDIR(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o700


def test_a_private_folder_never_reuses_what_is_there(
    shared: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    draws = iter([bytes(8), bytes(8), bytes([1] * 8)])
    monkeypatch.setattr(os, "urandom", lambda n: next(draws))
    (shared / ".saaaaaaaa").symlink_to(shared / "elsewhere")  # another user's, at the 1st name
    folder = files.private_folder(shared)
    assert folder.name == ".sbbbbbbbb"  # the third draw: the first two named the link
    assert os.path.islink(shared / ".saaaaaaaa") and not (shared / "elsewhere").exists()
    monkeypatch.setattr(os, "urandom", lambda n: bytes(8))
    with pytest.raises(OSError, match="no unused name for a private folder"):
        files.private_folder(shared)


def test_the_status_socket_cannot_be_bound_names_the_path(tmp_path: Path) -> None:
    long = tmp_path / ("d" * 120)
    long.mkdir()
    with pytest.raises(OSError):
        StatusServer(long / "status.sock", lambda histogram=False: {})
    assert [p.name for p in long.iterdir()] == []  # its private folder removed


# -- logging once -------------------------------------------------------------------------------
def test_each_trap_is_logged_once_at_warning(
    shared: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    path = shared / "trace.pcapng"
    place(path, "link")
    write_trace(path)
    write_trace(path)  # the second time the file is its own: no line
    lines = moved_aside_lines(caplog, path)
    assert len(lines) == 1
    assert [r.levelname for r in caplog.records if r.getMessage() == lines[0]] == ["WARNING"]
    assert (shared / "victim-of-trace.pcapng").read_bytes() == VICTIM_TEXT


# -- writes: complete or absent ------------------------------------------------------------------
def test_short_writes_are_completed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = os.write
    sizes: list[int] = []

    def short(fd: int, data: Any) -> int:
        sizes.append(len(data))
        return real(fd, bytes(data)[:7])  # the kernel may write less than asked

    monkeypatch.setattr(os, "write", short)
    payload = b"x" * 100
    write_atomic(tmp_path / "f", payload)
    assert (tmp_path / "f").read_bytes() == payload
    assert len(sizes) == 15


def test_a_write_that_returns_zero_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "f").write_bytes(b"good")
    monkeypatch.setattr(os, "write", lambda fd, data: 0)
    with pytest.raises(OSError):
        write_atomic(tmp_path / "f", b"new state")
    assert (tmp_path / "f").read_bytes() == b"good"  # never a truncated file in its place
    assert not (tmp_path / "f.tmp").exists()


def test_write_all_full_disk() -> None:
    r, w = os.pipe()
    os.close(r)
    with pytest.raises(OSError):
        write_all(w, b"x")  # EPIPE: any OSError propagates
    os.close(w)


def test_set_aside_fails_on_read_only_dir(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "state.json").write_bytes(b"\xff")
    with read_only(tmp_path):
        assert files.set_aside(tmp_path / "state.json") is None
    assert "cannot move" in caplog.text
