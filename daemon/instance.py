"""One daemon per state directory and per serial endpoint; on exit, remove only what it made.

A second motorctld with the same ``--state-dir`` or the same ``--pty`` path exits at once
with a message naming the first one's PID, before it touches any file: an exclusive
``flock`` on ``<state-dir>/motorctld.lock`` and on ``.<pty-name>.lock`` beside the PTY
symlink. (A UART is locked by pyserial's ``exclusive=True``, a flock on the device; its
holder is found in /proc/locks when that is visible.) The lock files hold the owner's PID;
what stands at their paths is dealt with as at every path the daemon writes
(daemon/paths.py), and a lock file another user left is set aside unless someone holds it.

:class:`Owned` records the files this daemon created (the PTY symlink, the status socket,
its lock files) with what they were when created, and removes each at exit only if it is
still the same file: never another daemon's, and never with a traceback (an unwritable
directory is logged and left).

Threads: all of it runs on the main thread, at start and at exit; nothing here blocks
except for the file system.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

from motorctl.daemon import paths

log = logging.getLogger("motorctl.instance")

LOCK_NAME = "motorctld.lock"


class InstanceError(Exception):
    """Another daemon holds the resource; the message names it, its PID and the fix."""


def flock_holder(path: Path) -> int | None:
    """The PID holding a flock on ``path``, from /proc/locks; None if unknown."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return _holder(st)


def _holder(st: os.stat_result) -> int | None:
    try:
        text = Path("/proc/locks").read_text()
    except OSError:
        return None
    dev = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in text.splitlines():
        parts = line.split()
        if "->" in parts:  # a waiter, not a holder
            continue
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == dev:
            with contextlib.suppress(ValueError):
                return int(parts[4])
    return None


def _pid_in(fd: int) -> int | None:
    """The PID a lock file holds (read through its descriptor: a regular file)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None


@dataclass
class InstanceLock:
    """An exclusive, non-blocking flock on ``path`` that names its holder's PID.

    The lock file is the daemon's own (daemon/paths.py): never a link followed, a FIFO or
    a device opened, a file of someone else's written. A regular file that another user
    left there is locked read-only first: held, it is another daemon's (InstanceError);
    not held, it is set aside while locked (so that nobody takes it meanwhile) and the
    daemon makes its own. Whatever else stands there is set aside.
    """

    path: Path
    what: str  # "state directory /run/motorctl", for the message
    fd: int | None = None
    ino: Identity | None = None

    def acquire(self) -> None:
        for _ in range(5):
            self._set_aside_if_foreign()
            try:
                fd = paths.open_for_writing(self.path)
            except OSError as exc:
                raise InstanceError(
                    f"cannot create lock file {self.path}: {exc.strerror or exc}"
                ) from exc
            try:
                self._lock(fd)
            except InstanceError:
                os.close(fd)
                raise
            # The previous holder may have removed the file between our open and our lock:
            # then we hold a lock on a file nobody else can find. Try again.
            st = os.fstat(fd)
            try:
                now = os.lstat(self.path)
            except FileNotFoundError:
                os.close(fd)
                continue
            if (st.st_dev, st.st_ino) != (now.st_dev, now.st_ino):
                os.close(fd)
                continue
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            self.fd, self.ino = fd, _identity(self.path)
            return
        raise InstanceError(f"cannot take the lock {self.path}: it keeps being replaced")

    def _lock(self, fd: int) -> None:
        """flock ``fd``; InstanceError naming the holder when another process holds it."""
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise InstanceError(f"cannot lock {self.path}: {exc.strerror}") from exc
            pid = _pid_in(fd) or _holder(os.fstat(fd))
            who = f"PID {pid}" if pid is not None else "a process whose PID is unknown"
            raise InstanceError(
                f"another motorctld ({who}) already serves the {self.what}; stop it "
                f"first, or give this one its own --state-dir and --pty/--port "
                f"(lock {self.path})"
            ) from None

    def _set_aside_if_foreign(self) -> None:
        """A regular lock file that is not ours (another user's, a hard link): another
        daemon's while someone holds it (InstanceError), else set aside while locked."""
        try:
            st = os.lstat(self.path)
        except OSError:
            return
        owner = paths.folder_owner(self.path)
        if not stat.S_ISREG(st.st_mode) or paths.ours(st, owner):
            return  # open_for_writing takes it, or sets it aside
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:
            return  # cannot be looked into: open_for_writing sets it aside
        try:
            now = os.fstat(fd)
            if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
                return  # replaced meanwhile: open_for_writing looks again
            self._lock(fd)
            try:
                bad = paths.move_aside(self.path)
            except OSError as exc:
                raise InstanceError(f"{exc.strerror}; lock {self.path}") from exc
            log.warning(
                "%s was %s, in the way of this daemon's lock: moved aside to %s",
                self.path,
                paths.describe(st, owner),
                bad,
                extra={"FILE_PATH": str(self.path)},
            )
        finally:
            os.close(fd)

    def release(self) -> None:
        """Remove the lock file (still ours: we hold the lock) and release it."""
        if self.fd is None:
            return
        _remove_if_same(self.path, self.ino)
        os.close(self.fd)
        self.fd = None


Identity = tuple[int, int, int]


def _identity(path: Path) -> Identity | None:
    """Device, inode and change time: an inode number alone is reused by the next file."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_ctime_ns


def _remove_if_same(path: Path, ino: Identity | None) -> bool:
    if ino is None or _identity(path) != ino:
        return False
    try:
        os.unlink(path)
    except FileNotFoundError:
        return False
    except OSError as exc:
        log.warning("cannot remove %s: %s; remove it by hand", path, exc.strerror)
        return False
    return True


@dataclass
class Owned:
    """Files this daemon created; :meth:`cleanup` removes those that are still its own."""

    symlinks: list[tuple[Path, str]] = field(default_factory=list)  # path, target
    files: list[tuple[Path, Identity | None]] = field(default_factory=list)
    locks: list[InstanceLock] = field(default_factory=list)

    def lock(self, path: Path, what: str) -> InstanceLock:
        lock = InstanceLock(path, what)
        lock.acquire()
        self.locks.append(lock)
        return lock

    def symlink(self, path: Path, target: str) -> None:
        self.symlinks.append((path, target))

    def file(self, path: Path) -> None:
        self.files.append((path, _identity(path)))

    def cleanup(self) -> None:
        for path, target in self.symlinks:
            try:
                if os.readlink(path) != target:
                    continue  # replaced by someone else: theirs now
                os.unlink(path)
            except FileNotFoundError:
                pass
            except OSError as exc:
                if exc.errno != errno.EINVAL:  # EINVAL: not a symlink, so not ours
                    log.warning("cannot remove %s: %s; remove it by hand", path, exc.strerror)
        for path, ino in self.files:
            _remove_if_same(path, ino)
        for lock in reversed(self.locks):
            lock.release()
        self.symlinks.clear()
        self.files.clear()
        self.locks.clear()
