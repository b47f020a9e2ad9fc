"""Safe files: what the daemon finds at the paths it writes, and how it makes its files there.

The one rule of every path the daemon creates or writes, kept in the state wing (whose files
are most of them) and used by every other part that writes a file: the lock files
(daemon/instance.py), the status socket (daemon/status/server.py), the trace
(daemon/link/recorder.py), the PTY's link (daemon/link/ports.py).

The daemon often runs as root with its files in folders that others can write: ``--pty
/tmp/x`` puts a lock file in /tmp, a ``--state-dir`` or a ``--trace`` file may be in a
shared folder. Whatever stands at a path it creates or writes (the state file and its
temporary file, the motion journal, the lock files, the status socket, the trace files) is
never written through, opened or waited for:

- a symbolic link is never followed (``O_NOFOLLOW``), not even one to a file of its own;
- a FIFO, a socket or a device is never opened: :func:`open_for_writing` looks with
  ``lstat`` first, opens with ``O_NONBLOCK`` and checks what it opened with ``fstat`` (a FIFO
  swapped in between is closed unread, unwritten);
- it writes only into a regular file it may call its own (:func:`ours`): one it created, or
  one with a single link owned by its own user or by the folder's owner. A file someone
  else left in a shared folder, or a hard link to a file elsewhere, is not;
- everything else is set aside under the first free name of ``NAME.bad``, ``NAME.bad.1``,
  ... ``NAME.bad.999`` (never replacing an older one, :func:`set_aside`), logged once, and
  the file is made anew with ``O_CREAT | O_EXCL``.

Complete or absent (:func:`write_atomic`, the state file): a temporary file is written in
full (looping on short writes, :func:`write_all`), fsynced, renamed over the file, and the
directory is fsynced (:func:`fsync_dir`).

The status socket is bound in a folder of its own making (mode 0700, so nobody can swap a
link in before its ``chmod``) and renamed into place (:func:`bind_socket`).

Threads: no state of its own; the thread that writes a file calls these (the main thread
at start and exit, the state writer, the trace writer). Nothing here blocks except on the
file system.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import socket
import stat
from pathlib import Path

log = logging.getLogger("motorctl.paths")

ASIDE_LIMIT = 1000  # names tried when setting a file aside: .bad, .bad.1 .. .bad.999
TRIES = 5  # a path that keeps being replaced while we make our file: give up, OSError

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISLNK, "a symbolic link"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)
_OPEN = os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC


def kind(mode: int) -> str:
    """What a file of this ``st_mode`` is, for a message: "a FIFO", "a directory", ..."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def folder_owner(path: Path) -> int:
    """The user owning the folder ``path`` is in (-1 when it cannot be looked at)."""
    try:
        return os.stat(path.parent).st_uid
    except OSError:
        return -1


def ours(st: os.stat_result, folder_uid: int) -> bool:
    """A regular file this process may write into without touching anyone else's: a single
    link, owned by this process's user or by the owner of its folder."""
    return stat.S_ISREG(st.st_mode) and st.st_nlink == 1 and st.st_uid in (os.geteuid(), folder_uid)


def describe(st: os.stat_result, folder_uid: int) -> str:
    """Why a file is not :func:`ours`, for the log line that sets it aside."""
    if not stat.S_ISREG(st.st_mode):
        return kind(st.st_mode)
    if st.st_nlink != 1:
        return f"a regular file with {st.st_nlink} hard links"
    if st.st_uid not in (os.geteuid(), folder_uid):
        return f"a regular file of another user (uid {st.st_uid})"
    return "a regular file"


def aside_name(path: Path) -> Path | None:
    """The first free name of ``<name>.bad``, ``<name>.bad.1``, ... (None: all taken)."""
    for n in range(ASIDE_LIMIT):
        bad = path.with_name(f"{path.name}.bad" + (f".{n}" if n else ""))
        if not os.path.lexists(bad):
            return bad
    return None


def move_aside(path: Path) -> Path:
    """Rename whatever is at ``path`` (a file, a directory, a link, ...; never opened,
    never followed) to :func:`aside_name`; the new name. OSError naming the path when it
    cannot."""
    bad = aside_name(path)
    if bad is None:
        raise OSError(
            errno.EEXIST,
            f"cannot move {path} aside: {path.name}.bad .. {path.name}.bad."
            f"{ASIDE_LIMIT - 1} are all taken; remove old ones",
        )
    try:
        os.rename(path, bad)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot move {path} aside to {bad}: {exc.strerror}") from exc
    return bad


def set_aside(path: Path) -> Path | None:
    """:func:`move_aside`; None (the reason logged) when it cannot be moved."""
    try:
        return move_aside(path)
    except OSError as exc:
        log.error("%s", exc.strerror, extra={"FILE_PATH": str(path), "ERRNO": exc.errno})
        return None


def aside_in_the_way(path: Path, what: str) -> Path:
    """Move what stands at ``path`` (``what``: "a FIFO", ...) aside (OSError if it cannot) and
    log it, once."""
    bad = move_aside(path)
    log.warning(
        "%s was %s, in the way of a file of this daemon: moved aside to %s",
        path,
        what,
        bad,
        extra={"FILE_PATH": str(path)},
    )
    return bad


def clear_the_way(path: Path) -> Path | None:
    """Set aside (and log) whatever stands at ``path`` that is not :func:`ours`: the name
    it was moved to, None when nothing had to move. OSError when it cannot be moved."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    owner = folder_owner(path)
    if ours(st, owner):
        return None
    return aside_in_the_way(path, describe(st, owner))


def open_for_writing(path: Path, mode: int = 0o640, flags: int = os.O_RDWR) -> int:
    """A descriptor (``flags``: O_RDWR or O_WRONLY) of a regular file at ``path`` that is
    :func:`ours`: the one there, or a new one (``mode``, less the umask) made after
    whatever else stood there was set aside and logged. Never follows a link, never opens
    a FIFO or a device, never truncates (the caller does, through the descriptor).
    OSError naming the path when no such file can be had (a folder that cannot be
    written, no free ``.bad`` name, a path that keeps being replaced)."""
    for _ in range(TRIES):
        try:
            st = os.lstat(path)
        except FileNotFoundError:
            try:
                return os.open(path, flags | os.O_CREAT | os.O_EXCL | _OPEN, mode)
            except FileExistsError:
                continue  # someone was quicker: look again
        owner = folder_owner(path)
        if not ours(st, owner):
            aside_in_the_way(path, describe(st, owner))
            continue
        try:
            fd = os.open(path, flags | _OPEN)
        except FileNotFoundError:
            continue
        except OSError as exc:
            if exc.errno not in (errno.ELOOP, errno.ENXIO, errno.EISDIR):
                raise
            continue  # replaced since the lstat (a link, a FIFO, a folder): look again
        now = os.fstat(fd)
        if (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino) and ours(now, owner):
            return fd
        os.close(fd)  # replaced since the lstat: look again
    raise OSError(errno.EAGAIN, f"{path} keeps being replaced; cannot make a file there")


def bind_socket(path: Path, mode: int) -> socket.socket:
    """A Unix stream socket bound at ``path`` with exactly ``mode`` (the umask does not
    apply). A socket already there is replaced (the caller holds the instance lock: it is a
    stale one); whatever else is there is set aside and logged. The socket is bound in a
    new folder only this process may write (``NAME/../.sXXXXXXXX/s``, as long as ``path``),
    chmodded there and renamed into place: nothing can be swapped in for it to chmod
    through. OSError when it cannot be bound."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        pass
    else:
        if not stat.S_ISSOCK(st.st_mode):
            aside_in_the_way(path, describe(st, folder_owner(path)))
    private = private_folder(path.parent)
    tmp = private / "s"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    try:
        sock.bind(str(tmp))
        os.chmod(tmp, mode)
        for _ in range(TRIES):
            try:
                os.rename(tmp, path)  # replaces a stale socket; never follows a link
                break
            except OSError as exc:
                if exc.errno not in (errno.EISDIR, errno.ENOTEMPTY, errno.EEXIST):
                    raise
                aside_in_the_way(path, "a directory")  # made there since the lstat
        else:
            raise OSError(errno.EAGAIN, f"{path} keeps being replaced; cannot bind there")
    except BaseException:
        sock.close()
        raise
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)  # still there when the rename did not happen
        os.rmdir(private)
    return sock


#: the characters of a private folder's name (tempfile's own), and how many follow its ".s"
_NAME_CHARS = "abcdefghijklmnopqrstuvwxyz0123456789_"
_NAME_LEN = 8
#: the bytes a Unix socket's path may hold (sun_path, less its NUL)
SOCKET_PATH_MAX = 107
#: what :func:`bind_socket` adds to the path of the folder it binds in, while it binds:
#: ``/.sXXXXXXXX/s``, its private folder's socket (longer than ``/status.sock``)
BIND_SUFFIX = len("/.s") + _NAME_LEN + len("/s")


def private_folder(parent: Path) -> Path:
    """A new folder ``.sXXXXXXXX`` in ``parent`` (8 random characters) that only this
    process's user may enter (0700), as ``tempfile.mkdtemp(prefix=".s")`` makes one: made by
    ``mkdir``, which fails on anything already there (never followed, never reused). Without
    tempfile, whose imports (random, shutil and its compressors) every start paid for this
    one folder. OSError when none can be made."""
    for _ in range(TRIES):
        name = ".s" + "".join(_NAME_CHARS[b % len(_NAME_CHARS)] for b in os.urandom(_NAME_LEN))
        try:
            os.mkdir(parent / name, 0o700)
        except FileExistsError:
            continue
        return parent / name
    raise OSError(errno.EEXIST, f"no unused name for a private folder in {parent}")


# -- complete or absent ---------------------------------------------------------------------
def write_all(fd: int, data: bytes) -> None:
    """Write every byte, looping on short writes (a full disk raises OSError)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        if n <= 0:
            raise OSError(errno.EIO, "write returned 0")
        view = view[n:]


def fsync_dir(path: Path) -> None:
    dfd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def write_atomic(path: Path, data: bytes, mode: int = 0o640) -> None:
    """Replace ``path`` with ``data``, complete or not at all; OSError when it cannot."""
    tmp = path.with_name(path.name + ".tmp")
    fd = open_for_writing(tmp, mode, os.O_WRONLY)  # what else is there is set aside
    try:
        try:
            os.ftruncate(fd, 0)
            write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        try:
            os.replace(tmp, path)  # replaces a link or a FIFO there, never follows it
        except IsADirectoryError:  # a directory made there since the start
            clear_the_way(path)
            os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)
