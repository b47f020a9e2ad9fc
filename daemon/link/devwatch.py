"""A serial device that is away, for the link: its return noticed at once (:class:`PathWatch`:
inotify on the folders of its path) and its path tried again (:class:`DeviceReturn`: on
the watch's news, and on a bounded backoff besides); and the inotify primitives the PTY's
slave watch uses too (:func:`inotify`, :func:`read_events`; daemon/link/ports.py).

A USB adapter plugged back in (or in for the first time) makes udev create its node in
``/dev`` and its names in ``/dev/serial/by-id/`` (a link, made in place or renamed into
place), then give the node its group and mode; a socat PTY pair made again creates its
links anew. Each is an inotify event in a folder of the device's *path*: the folder of the
name the daemon was given, of every link it leads through (``by-id/usb-...`` ->
``../../ttyUSB0``), and, where a folder itself is missing (``/dev/serial`` goes with the
last adapter), of the nearest one that exists, for the missing folder's name.
:class:`PathWatch` watches exactly those folders, for those names only, so that the link
(daemon/link/loop.py) tries to open the device the moment something there changes, instead of
only on its backoff schedule (which goes on, bounded, as the fallback: an event inotify
cannot see, such as a change on another machine's file system, or no inotify at all).

inotify is reached through the C library (``inotify_init1``, ``inotify_add_watch``,
``inotify_rm_watch``; ctypes, no extra package): Python's standard library has no binding.
It is the interpreter's own C library (``CDLL(None)``), never looked up with
``ctypes.util.find_library``, which runs ``ldconfig -p`` in a process of its own: the PTY's
watch is made at every start, and that look-up was most of the PTY's share of the start.

Threads: owned by the link thread (armed at a loss, read while the device is away,
disarmed when it is back).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import logging
import os
import struct
from collections import Counter
from typing import Protocol

from motorctl.daemon.link.serialport import Backoff, DeviceError

log = logging.getLogger("motorctl.link")

IN_ATTRIB = 0x00000004  # the node's mode or owner changed (udev gives it its group)
IN_CLOSE_WRITE = 0x00000008  # a description of the file opened for writing was closed
IN_CLOSE_NOWRITE = 0x00000010  # one opened read-only
IN_OPEN = 0x00000020
IN_MOVED_TO = 0x00000080  # a name renamed into the folder (udev's links)
IN_CREATE = 0x00000100  # a name created in it (a node, a link, a folder)
IN_DELETE_SELF = 0x00000400
IN_MOVE_SELF = 0x00000800
IN_Q_OVERFLOW = 0x00004000  # events were lost: look anyway
IN_IGNORED = 0x00008000  # the watch went (its folder was removed): watch again
IN_ONLYDIR = 0x01000000
IN_NONBLOCK = os.O_NONBLOCK
IN_CLOEXEC = os.O_CLOEXEC

WATCH_MASK = IN_CREATE | IN_MOVED_TO | IN_ATTRIB | IN_DELETE_SELF | IN_MOVE_SELF | IN_ONLYDIR
#: events that say "look again" whatever name they carry
ANY_NAME = IN_Q_OVERFLOW | IN_IGNORED | IN_DELETE_SELF | IN_MOVE_SELF
_EVENT = struct.Struct("iIII")  # struct inotify_event: wd, mask, cookie, len (then the name)
MAX_LINKS = 40  # as the kernel's own limit on links followed in one lookup


def inotify(path: str, mask: int) -> int:
    """A non-blocking inotify descriptor watching ``path`` for ``mask``; OSError if not."""
    libc = _libc()
    if libc is None:
        raise OSError(errno.ENOSYS, "no C library with inotify")
    fd = int(libc.inotify_init1(IN_NONBLOCK | IN_CLOEXEC))
    if fd < 0:
        code = ctypes.get_errno()
        raise OSError(code, f"inotify_init1: {os.strerror(code)}")
    if libc.inotify_add_watch(fd, os.fsencode(path), mask) < 0:
        code = ctypes.get_errno()
        os.close(fd)
        raise OSError(code, f"inotify_add_watch {path}: {os.strerror(code)}")
    return fd


#: bytes asked of one read of an inotify descriptor
_READ_SIZE = 65536
#: a read that returned less than this took every event pending: the next one (16 bytes and a
#: name of up to NAME_MAX bytes, NUL-padded) would have fitted
_READ_ALL = _READ_SIZE - (16 + 256)


def read_events(fd: int) -> list[tuple[int, int, str]]:
    """Every event pending on inotify descriptor ``fd``: (watch, mask, name).

    One read takes them all unless the buffer filled up (a read returns every pending event
    that fits): then it reads again. An event that comes after the last read makes ``fd``
    readable again. (No read that can only say EAGAIN: the PTY's watch is asked on every
    read of the port, and a system call there shows in every round trip.)"""
    out: list[tuple[int, int, str]] = []
    while True:
        try:
            data = os.read(fd, _READ_SIZE)
        except BlockingIOError:
            return out
        pos = 0
        while pos + _EVENT.size <= len(data):
            wd, mask, _cookie, size = _EVENT.unpack_from(data, pos)
            name = data[pos + _EVENT.size : pos + _EVENT.size + size].rstrip(b"\0")
            pos += _EVENT.size + size
            out.append((wd, mask, os.fsdecode(name) if name else ""))
        if len(data) < _READ_ALL:
            return out


def _libc() -> ctypes.CDLL | None:
    try:
        # the interpreter's own C library: ctypes.util.find_library would run ldconfig (and
        # gcc, ld or objdump from PATH where that finds nothing) in the daemon
        libc = ctypes.CDLL(None, use_errno=True)
        libc.inotify_init1.argtypes = [ctypes.c_int]
        libc.inotify_add_watch.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_uint32]
        libc.inotify_rm_watch.argtypes = [ctypes.c_int, ctypes.c_int]
    except (OSError, AttributeError):  # no C library, or one without inotify
        return None
    return libc


def watched_names(path: str) -> dict[str, set[str]]:
    """The folders to watch for ``path`` and, in each, the names that matter: the path's
    own, every link's target along the way, and for a folder that does not exist, its name
    in the nearest folder that does."""
    out: dict[str, set[str]] = {}
    current = os.path.abspath(path)
    for _ in range(MAX_LINKS):
        folder, name = os.path.split(current)
        # the nearest folder that exists, and the name to wait for in it
        while folder and not os.path.isdir(folder):
            folder, name = os.path.split(folder)
        out.setdefault(folder or "/", set()).add(name)
        try:
            target = os.readlink(current)
        except OSError:  # not a link (the node itself, or nothing yet): the end of the chain
            break
        current = os.path.normpath(os.path.join(os.path.dirname(current), target))
    return out


class PathWatch:
    """inotify watches on the folders of a device's path (:func:`watched_names`)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._fd = -1
        self._names: dict[int, set[str]] = {}  # watch descriptor -> names that matter there
        self._libc: ctypes.CDLL | None = None
        self._failed = False  # inotify could not be had: said once, polled from then on

    @property
    def fd(self) -> int | None:
        """The descriptor to wait on for events (None: not armed, or no inotify)."""
        return self._fd if self._fd >= 0 else None

    def arm(self) -> bool:
        """Watch the path's folders as they are now (again: links may lead elsewhere now).
        False when inotify cannot be used here; said once, and the link's backoff alone
        then notices the device's return."""
        if self._failed:
            return False
        if self._fd < 0:
            self._libc = self._libc or _libc()
            fd = -1 if self._libc is None else self._libc.inotify_init1(IN_NONBLOCK | IN_CLOEXEC)
            if fd < 0:
                code = ctypes.get_errno() if self._libc is not None else errno.ENOSYS
                return self._give_up(f"inotify_init1: {os.strerror(code)}")
            self._fd = fd
        assert self._libc is not None
        # a folder watched already keeps its watch descriptor (inotify_add_watch returns
        # it again): removing and adding it would queue an IN_IGNORED for nothing
        # A folder made between reading the path and watching its parent (mkdir -p of
        # serial/by-id) sends its event to no one: read the path again once the watches are
        # in place, until it reads the same (bounded: each round follows a real change).
        wanted_before: dict[str, set[str]] | None = None
        names: dict[int, set[str]] = {}
        added: set[int] = set()
        for _ in range(MAX_LINKS):
            wanted_now = watched_names(self.path)
            if wanted_now == wanted_before:
                break
            wanted_before = wanted_now
            names = {}
            for folder, wanted in wanted_now.items():
                wd = self._libc.inotify_add_watch(self._fd, os.fsencode(folder), WATCH_MASK)
                if wd < 0:
                    code = ctypes.get_errno()
                    if code in (errno.ENOENT, errno.ENOTDIR):  # gone meanwhile: its parent's
                        continue  # event (watched too) brings another look
                    return self._give_up(f"inotify_add_watch {folder}: {os.strerror(code)}")
                names.setdefault(wd, set()).update(wanted)
                added.add(wd)
        for wd in (set(self._names) | added) - set(names):
            self._libc.inotify_rm_watch(self._fd, wd)
        self._names = names
        return True

    def changed(self) -> bool:
        """Read the pending events; True if one concerns the path (then it is armed again,
        since a link or a folder may have appeared)."""
        if self._fd < 0:
            return False
        try:
            events = read_events(self._fd)
        except OSError as exc:
            self._give_up(f"reading inotify events: {exc.strerror}")
            return True  # look once more; the backoff goes on from here
        hit = any(
            mask & IN_Q_OVERFLOW  # events were lost: look anyway
            or (wd in self._names and (mask & ANY_NAME or name in self._names[wd]))
            for wd, mask, name in events  # (a watch dropped already is not in _names)
        )
        if hit:
            self.arm()
        return hit

    def disarm(self) -> None:
        """No more events wanted (the device is back); the descriptor stays for next time."""
        self._drop_watches()
        if self._fd >= 0:  # events that came meanwhile are of no use
            with contextlib.suppress(OSError):
                while os.read(self._fd, 65536):
                    pass

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)  # its watches go with it
        self._fd = -1
        self._names.clear()

    def _drop_watches(self) -> None:
        if self._fd >= 0 and self._libc is not None:
            for wd in self._names:
                self._libc.inotify_rm_watch(self._fd, wd)
        self._names.clear()

    def _give_up(self, why: str) -> bool:
        self._failed = True
        self.close()
        log.warning(
            "cannot watch the folders of %s for its return (%s): looking for it on the "
            "backoff schedule only (at least every second)",
            self.path,
            why,
            extra={"DEVICE": self.path},
        )
        return False


# -- trying the path again ------------------------------------------------------------------
#: errors of an open that only say the device is not back yet (logged at debug level); any
#: other (no permission, busy) is logged once as a warning: the user must act
NOT_BACK = frozenset({errno.ENOENT, errno.ENXIO, errno.ENODEV, errno.EIO})


class Device(Protocol):
    """A serial device that can be opened again by its path (daemon.serialport)."""

    path: str

    def open(self) -> int: ...  # a fresh non-blocking descriptor, or DeviceError

    def close(self) -> None: ...


class Notice(Protocol):
    """Tells when something changed on a device's path (:class:`PathWatch`)."""

    @property
    def fd(self) -> int | None: ...  # readable when there is news; None: none to wait on

    def arm(self) -> bool: ...

    def changed(self) -> bool: ...

    def disarm(self) -> None: ...

    def close(self) -> None: ...


class DeviceReturn:
    """When to open an absent device's path again, and the opening: at once when ``notice``
    has news of the path, and on ``backoff``'s schedule besides (the fallback, bounded by its
    longest pause). ``counters`` (the link's) count ``reopen_attempts`` and
    ``device_reopened``; the log says once why a device that is there cannot be opened, and
    when it is back (or there at last, for one that was not there at start)."""

    def __init__(
        self,
        device: Device,
        notice: Notice | None,
        backoff: Backoff,
        counters: Counter[str],
    ) -> None:
        self.device = device
        self.notice = notice
        self.backoff = backoff
        self.counters = counters
        self.ever_open = True  # False until a device not there at start appears
        self._since = 0.0  # when it went away
        self._next = 0.0  # when the schedule tries next
        self._attempts = 0  # since it went away
        self._reported: set[int | None] = set()  # the errors logged since then

    def awaited(self, now: float) -> None:
        """Not there at start (from ``now`` on): served as soon as it appears."""
        self.ever_open = False
        self.away(now)
        log.warning(
            "serial device %s is not there: serving it as soon as it appears (watching "
            "its folder, and trying every %.0f ms at most)",
            self.device.path,
            self.backoff.max_s * 1000,
            extra={"DEVICE": self.device.path, "EVENT": "device_awaited"},
        )

    def lost(self, why: str, now: float) -> None:
        """It went away at ``now`` (``why``, for the log): its dead descriptor is closed;
        it is opened again when it is back. Motors and positions are kept."""
        path = self.device.path
        self.device.close()
        self.away(now)
        self.counters["device_lost"] += 1  # once its path is watched (the tests wait on it)
        log.warning(
            "serial device %s is gone (%s); motors and positions are kept; opening %s "
            "again as soon as it is back (watching its folder, and trying %.0f ms after "
            "the loss, then doubling up to every %.0f ms)",
            path,
            why,
            path,
            self.backoff.first_s * 1000,
            self.backoff.max_s * 1000,
            extra={"DEVICE": path, "EVENT": "device_lost"},
        )

    def away(self, now: float) -> None:
        """It is away from ``now`` on: watch its path, start the schedule from its first
        pause."""
        self._since = now
        self._attempts = 0
        self._reported = set()
        self.backoff.reset()
        self._next = now + self.backoff.delay()
        if self.notice is not None:
            self.notice.arm()

    def wait_s(self, now: float) -> float:
        """How long until the schedule's next attempt."""
        return self._next - now

    @property
    def fds(self) -> list[int]:
        """What to wait on besides the time: the watch's descriptor, if any."""
        fd = None if self.notice is None else self.notice.fd
        return [] if fd is None else [fd]

    def look(self, ready: list[int], now: float) -> int | None:
        """After a wait: the new descriptor if it is time (or the path changed) and the open
        worked, else None."""
        news = bool(set(ready) & set(self.fds))
        noticed = news and self.notice is not None and self.notice.changed()
        if now < self._next and not noticed:
            return None
        return self._try(now, noticed)

    def _try(self, now: float, noticed: bool) -> int | None:
        """Open the path; ``noticed``: because something changed there (such an attempt
        does not move the schedule)."""
        device = self.device
        self._attempts += 1
        self.counters["reopen_attempts"] += 1
        try:
            fd = device.open()
        except DeviceError as exc:
            if not noticed:
                self._next = now + self.backoff.delay()
            # A node that just appeared may not have its group and mode yet (udev gives
            # them a moment later): only a scheduled attempt says so, once per reason.
            if exc.errno in NOT_BACK or exc.errno in self._reported or noticed:
                log.debug("%s; trying again in %.0f ms", exc, (self._next - now) * 1000)
            else:  # there, but not usable: the user must act (it is retried all the same)
                self._reported.add(exc.errno)
                log.warning(
                    "%s; trying again (every %.0f ms at most)",
                    exc,
                    self.backoff.max_s * 1000,
                    extra={"DEVICE": device.path},
                )
            return None
        if self.notice is not None:
            self.notice.disarm()
        if not self.ever_open:
            self.ever_open = True
            log.info(
                "serial device %s is there after %.1f s (%d attempts): serving it",
                device.path,
                now - self._since,
                self._attempts,
                extra={"DEVICE": device.path, "EVENT": "device_appeared"},
            )
        else:
            self.counters["device_reopened"] += 1
            log.info(
                "serial device %s is back after %.1f s (%d attempts): serving again",
                device.path,
                now - self._since,
                self._attempts,
                extra={"DEVICE": device.path, "EVENT": "device_back"},
            )
        return fd

    def close(self) -> None:
        if self.notice is not None:
            self.notice.close()
