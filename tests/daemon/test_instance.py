"""One daemon per state directory and serial endpoint (daemon/instance.py): the lock names its
holder (from the lock file, or /proc/locks), a lock where none can be made is an error
naming it, and ``Owned`` removes at exit only the files that are still its own."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from motorctl.daemon.instance import InstanceError, InstanceLock, Owned, flock_holder
from tests.support.fsutil import read_only


def test_lock_names_the_holder(tmp_path: Path) -> None:
    first = InstanceLock(tmp_path / "x.lock", "state directory X")
    first.acquire()
    assert (tmp_path / "x.lock").read_text() == f"{os.getpid()}\n"
    assert flock_holder(tmp_path / "x.lock") == os.getpid()
    second = InstanceLock(tmp_path / "x.lock", "state directory X")
    with pytest.raises(InstanceError, match=f"PID {os.getpid()}.*state directory X"):
        second.acquire()
    first.release()
    assert not (tmp_path / "x.lock").exists()
    second.acquire()
    second.release()


def test_lock_holder_from_proc_locks_when_the_file_says_nothing(tmp_path: Path) -> None:
    first = InstanceLock(tmp_path / "x.lock", "PTY")
    first.acquire()
    os.truncate(tmp_path / "x.lock", 0)
    with pytest.raises(InstanceError, match=f"PID {os.getpid()}"):
        InstanceLock(tmp_path / "x.lock", "PTY").acquire()
    first.release()
    assert flock_holder(tmp_path / "nothing") is None


def test_lock_in_unwritable_place(tmp_path: Path) -> None:
    with pytest.raises(InstanceError, match="cannot create lock file"):
        InstanceLock(tmp_path / "missing" / "x.lock", "X").acquire()


def test_owned_removes_only_its_own(tmp_path: Path) -> None:
    owned = Owned()
    owned.lock(tmp_path / "a.lock", "A")
    link = tmp_path / "pty"
    link.symlink_to("/dev/pts/999")
    owned.symlink(link, "/dev/pts/999")
    other = tmp_path / "other"
    other.symlink_to("/dev/pts/1")
    owned.symlink(other, "/dev/pts/2")  # re-pointed by someone else: theirs now
    mine = tmp_path / "mine"
    mine.write_text("x")
    owned.file(mine)
    replaced = tmp_path / "replaced"
    replaced.write_text("x")
    owned.file(replaced)
    replaced.unlink()
    replaced.write_text("new")
    plain = tmp_path / "plain"
    plain.write_text("not a link")
    owned.symlink(plain, "x")
    owned.symlink(tmp_path / "gone", "x")
    owned.cleanup()
    assert not link.is_symlink() and other.is_symlink() and not mine.exists()
    assert replaced.read_text() == "new" and plain.exists()
    assert not (tmp_path / "a.lock").exists()


def test_owned_cleanup_on_read_only_dir(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    owned = Owned()
    link = tmp_path / "pty"
    link.symlink_to("/dev/pts/999")
    owned.symlink(link, "/dev/pts/999")
    with read_only(tmp_path):
        owned.cleanup()
    assert link.is_symlink() and "cannot remove" in caplog.text
