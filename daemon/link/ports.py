"""Where the daemon serves: a new PTY (``--pty``), and its slave side held while no host has it.

A UART (``--port``) is opened by daemon/link/serialport.py.

Threads: the main thread, at start-up (the assembler, daemon/start/assemble.py); the descriptors
it returns, and the :class:`PtySlave`, then belong to the link (daemon/link/loop.py).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import select
import stat
import termios
import tty
from pathlib import Path

from motorctl.daemon.errors import StartupError
from motorctl.daemon.link import devwatch
from motorctl.daemon.state import files


def open_pty(path: Path) -> tuple[int, str]:
    """A new PTY in raw mode; ``path`` becomes a symlink to its slave. Returns the master fd
    and the slave's name.

    The daemon does not keep the slave open while a host has it (the master then sees the
    host close the port: POLLHUP, EIO); while no host has, it holds it (:class:`PtySlave`).
    The raw mode stays set while the master is open.

    The slave is mode 0660 with the daemon's group (the ``motorctl`` group under systemd):
    only that group's members may drive the motors.

    What stands at ``path`` is never opened or followed: a link (the one an earlier run left,
    or anyone's) is replaced; a device is refused (``--pty /dev/ttyS0`` is a mistake, and
    renaming a device node breaks a system); anything else (a FIFO, a folder, a file) is set
    aside under ``NAME.bad`` with one log line (daemon/state/files.py), and the start goes on."""
    _clear_pty_path(path)
    master, slave = os.openpty()
    tty.setraw(slave, termios.TCSANOW)
    name = os.ttyname(slave)
    os.chown(name, -1, os.getegid())
    os.chmod(name, 0o660)
    os.close(slave)
    os.set_blocking(master, False)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        os.symlink(name, tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise StartupError(f"cannot create symlink {path}: {exc.strerror}") from exc
    return master, name


def _clear_pty_path(path: Path) -> None:
    """Make way for the PTY's link at ``path`` (see :func:`open_pty`); StartupError when it
    cannot be made."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise StartupError(f"cannot look at --pty path {path}: {exc.strerror}") from exc
    if stat.S_ISLNK(st.st_mode):
        return
    what = files.kind(st.st_mode)
    if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode):
        raise StartupError(
            f"{path} is {what}: --pty names the link the daemon makes to its own PTY; "
            "choose another path (a UART is served with --port)"
        )
    try:
        files.aside_in_the_way(path, what)
    except OSError as exc:
        raise StartupError(f"{exc.strerror}; remove it or choose another --pty path") from exc


log = logging.getLogger("motorctl.link")

#: ioctl: a new descriptor of a PTY master's slave, without a lookup by name (Linux >= 4.13)
TIOCGPTPEER = getattr(termios, "TIOCGPTPEER", 0x5441)
#: what is watched on the slave's node: a description opened, one opened for writing closed
OPENS = devwatch.IN_OPEN | devwatch.IN_CLOSE_WRITE


class PtySlave:
    """The slave side of the daemon's PTY: held open by the daemon while no host has it,
    and watched, so that the link knows when a host's session ended.

    **Holding.** A PTY master whose slave nobody has open reports POLLHUP at once, every time
    it is polled: the link could only look every so often whether a host is back, and a new
    host's first command waited for that look. With the slave held here (read-only), the
    master is quiet until a host writes, and the link's ``poll()`` wakes at its first byte;
    the link lets go of the slave then (:meth:`release`), so that this host's close is seen
    in turn. :meth:`hold` also takes what the host that went left unread in the slave's
    input (the kernel keeps it for whoever opens the slave next, who would read answers to
    someone else's questions): it counts those bytes and flushes them.

    **Watching.** The master's POLLHUP says that nobody has the slave open *now*; a host
    that closes the port and opens it again at once (a reconnect, a quick restart) can be
    back before the link looks, and its first frames would join the old session, behind
    the old host's WaitMoved. inotify on the slave's node reports, in order, each close of a
    description opened for writing (``IN_CLOSE_WRITE``: a host's; the daemon's own hold is
    read-only) and each open (``IN_OPEN``). :meth:`reopened` says when the port was opened
    again after a host closed it: that host's session has ended, even though the master
    never reported the hang-up. (inotify merges identical events that follow each other,
    so they are not counted: only their order is used.) The link takes these events before
    the bytes that follow them (:attr:`events_fd` is in its poll set), so a new host's bytes
    always find the old session ended. Without inotify, POLLHUP alone says it (said once
    in the log).

    Failures are logged once, never raised: the link then looks for a host every
    ``retry_s`` instead of holding the slave."""

    def __init__(self, master: int, name: str, watch: bool = True) -> None:
        self.master = master
        self.name = name
        self._fd = -1
        self._warned = False
        self._events = -1
        self._closed = False  # a host closed a writable description since the session began
        # asked whether events are pending before they are read: a poll that finds none
        # costs a third of a read that fails (a raised BlockingIOError), on every read
        self._pending = select.poll()
        if watch:
            try:
                self._events = devwatch.inotify(name, OPENS)
                self._pending.register(self._events, select.POLLIN)
            except OSError as exc:
                log.warning(
                    "cannot watch %s for its opens and closes (%s): a host that closes the "
                    "port and opens it again at once may be taken for the same host",
                    name,
                    exc.strerror or exc,
                )

    @property
    def held(self) -> bool:
        return self._fd >= 0

    @property
    def events_fd(self) -> int | None:
        """Readable when the slave was opened, or closed by a writer (None: not watched)."""
        return self._events if self._events >= 0 else None

    def reopened(self) -> bool:
        """Take the events that came: True when, since the session began (:meth:`release`),
        a host closed a description it could write through and the slave was opened after
        that."""
        if self._events < 0 or not self._pending.poll(0):
            return False
        for _wd, mask, _name in devwatch.read_events(self._events):
            if mask & devwatch.IN_CLOSE_WRITE:
                self._closed = True
            elif mask & devwatch.IN_OPEN and self._closed:
                return True  # what follows is the next session's (the next call's)
            elif mask & (devwatch.IN_Q_OVERFLOW | devwatch.IN_IGNORED):  # order lost
                self._unwatch("its events overflowed or its node went")
                return True
        return False

    def hold(self, answered: bool = True) -> int:
        """Open the slave (read-only) and keep it; the bytes the last host left unread,
        flushed. ``answered``: whether anything was written to that host since its session
        began (:meth:`release`); if not, nothing of the daemon's can be waiting in the
        slave's input (only the master writes there, and the daemon alone has the master),
        and it is not looked at."""
        self._closed = False  # the session ended: its closes are accounted for
        if self._fd >= 0:
            return 0
        flags = os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK | os.O_CLOEXEC
        try:  # no lookup by name
            fd = fcntl.ioctl(self.master, TIOCGPTPEER, flags)
        except OSError:  # an older kernel: by its name (a /dev/pts node, never a link)
            try:
                fd = os.open(self.name, flags | os.O_NOFOLLOW)
            except OSError as exc:
                self._warn(f"cannot open {self.name}: {exc.strerror}")
                return 0
        self._fd = fd
        return self._flush(fd) if answered else 0

    def _flush(self, fd: int) -> int:
        """Read out and count what is waiting in the slave's input, then flush it."""
        stale = 0
        try:
            # Read, not just counted: a read that finds nothing waits for what the master
            # wrote last to reach the slave's input (the kernel moves it there on a worker
            # thread, a moment later), so an answer written just before the host closed is
            # counted too.
            while chunk := os.read(fd, 4096):
                stale += len(chunk)
        except BlockingIOError:
            pass
        except OSError as exc:
            self._warn(f"cannot read what the last host left unread on {self.name}: {exc}")
        try:
            # A canonical mode (a host may leave one set) keeps the last partial line
            # unreadable, and the kernel does not count it either (FIONREAD counts whole
            # lines): it is flushed uncounted.
            termios.tcflush(fd, termios.TCIFLUSH)
        except termios.error as exc:
            self._warn(f"cannot flush what the last host left unread on {self.name}: {exc}")
        return stale

    def release(self) -> None:
        """Let go of the slave (a host has it now: its session begins). Before the host's
        first answers are written: a close just after them holds up the host's read of
        them (by some 25 us here)."""
        self._closed = False
        fd, self._fd = self._fd, -1
        if fd >= 0:
            with contextlib.suppress(OSError):
                os.close(fd)

    def close(self) -> None:
        self.release()
        self._unwatch(None)

    def _unwatch(self, why: str | None) -> None:
        if self._events >= 0:
            self._pending.unregister(self._events)
            os.close(self._events)
            self._events = -1
            if why is not None:
                log.warning(
                    "no longer watching %s for its opens and closes (%s): a host that "
                    "closes the port and opens it again at once may be taken for the same "
                    "host",
                    self.name,
                    why,
                )

    def _warn(self, message: str) -> None:
        if not self._warned:
            self._warned = True
            log.warning("%s; looking for a new host every 20 ms instead", message)
