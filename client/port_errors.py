"""Why ``motorctl`` cannot open its port, in one line with what to do about it.

pyserial's errors repeat themselves (``could not open port X: [Errno 2] No such file or
directory: 'X'``) or name an ioctl (``Could not configure port: (25, 'Inappropriate ioctl
for device')``). :func:`not_a_port` refuses, before anything is opened, what is not a
character device (a regular file, a folder, a FIFO); :func:`open_error` turns a failed
open into the cause and its fix:

- no such file: motorctld is most likely not running (the PTY is its link, made when it
  starts and removed when it stops), or the device is not there;
- permission denied: the group the device (or a folder on its way) belongs to, to join;
- busy: another program has it open exclusively;
- not a terminal (``/dev/null``), or a baud rate the UART's driver refuses.

Threads: the caller's; nothing here blocks but ``stat``.
"""

from __future__ import annotations

import errno
import grp
import os
import stat
from pathlib import Path

__all__ = ["DEFAULT_PORT", "not_a_port", "open_error"]

#: where the packaged service serves (systemd/motorctld.default's MOTORCTLD_SERVE; `make
#: run` serves ./motorctl.pty)
DEFAULT_PORT = "/run/motorctl/motorctl.pty"

_KINDS = (
    (stat.S_ISREG, "a regular file"),
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISBLK, "a block device"),
)


def not_a_port(port: str) -> str | None:
    """The message for a ``port`` that exists and is no character device (never opened:
    a FIFO would wait for a writer); None when it may be tried."""
    try:
        mode = os.stat(port).st_mode
    except OSError:
        return None  # the open says why
    for test, what in _KINDS:
        if test(mode):
            return f"{port}: not a serial device ({what})"
    return None


def _errno_of(exc: BaseException) -> int | None:
    """The errno behind pyserial's exception (its own, or the one it was raised from)."""
    seen: BaseException | None = exc
    while seen is not None:
        code = getattr(seen, "errno", None)
        if isinstance(code, int):
            return code
        seen = seen.__cause__ or seen.__context__
    if "configure port" in str(exc) and "25" in str(exc):
        return errno.ENOTTY  # tcgetattr on something that is not a terminal
    return None


def open_error(port: str, exc: BaseException, baud: int) -> str:
    """One line: why ``port`` could not be opened at ``baud``, and the fix."""
    if "custom baud rate" in str(exc):
        return (
            f"cannot open {port}: its driver refuses {baud} baud, which is not one of the "
            "rates termios names (9600, 19200, 38400, 57600, 115200, 230400, ...)"
        )
    code = _errno_of(exc)
    if code == errno.ENOENT:
        return f"cannot open {port}: {_missing(port)}"
    if code in (errno.EACCES, errno.EPERM):
        return f"cannot open {port}: permission denied: {_denied(port)}"
    if code in (errno.EBUSY, errno.EAGAIN):
        return (
            f"cannot open {port}: busy: another program has it open exclusively (a "
            "terminal program, a getty such as serial-getty@, ModemManager); stop it first"
        )
    if code == errno.ENOTTY:
        return f"{port}: not a serial device (a character device that is not a terminal)"
    text = os.strerror(code) if code is not None else str(exc)
    return f"cannot open {port}: {text}"


def _missing(port: str) -> str:
    """No such file: a link left by a daemon that is gone, or nothing at all."""
    hint = f"is motorctld running? its default port is {DEFAULT_PORT}"
    try:
        target = os.readlink(port)
    except OSError:
        return f"no such file ({hint})"
    return f"no such file: it is a link to {target}, which is gone ({hint})"


def _denied(port: str) -> str:
    """Whose group to join: the folder on the way that we may not enter, or the device."""
    path = Path(os.path.abspath(port))
    for folder in reversed(path.parents):
        if not os.access(folder, os.X_OK):
            return f"the folder {folder} is not open to this user ({_group_fix(folder)})"
    return f"it is not open to this user ({_group_fix(path)})"


def _group_fix(path: Path) -> str:
    try:
        st = path.stat()
    except OSError:
        return "ls -l it to see whose it is"
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    mode = stat.filemode(st.st_mode)
    return (
        f"{mode}, group {group}: join the group with 'sudo adduser $USER {group}' and log in again"
    )
