"""The serial device behind ``--port``: opened by its path, and opened again by its path.

A USB serial adapter that is unplugged takes its tty with it: the descriptor the daemon
holds is hung up for good (POLLHUP, reads of nothing, EIO), and the adapter plugged back in
is a new device that must be opened anew. :class:`SerialDevice` keeps the *path* it was given
(``/dev/ttyUSB0``, or better udev's ``/dev/serial/by-id/usb-...`` name, which follows the
adapter whichever ``ttyUSBn`` it becomes) and opens it again on request; the link
(:mod:`motorctl.daemon.link`) decides when, on a :class:`Backoff` schedule.

Every failure a user can cause (no such device, no permission, held by another program, not
a serial device) is a :class:`DeviceError` whose message names the path and the fix.

The device is opened with pyserial (baud rate, 8N1, no flow control, an exclusive ``flock``
so a second program cannot open it too) and then made to answer a read with nothing to read
with EAGAIN instead of an empty read (``VMIN = 1``; pyserial leaves 0): an empty read then
means only one thing, a device that hung up. pyserial's ``open()`` flushes the input; ours
does not (:class:`KeepInput`): bytes the host sent after its device came back, before the
daemon opened it again, are its new session's first frames and are read, not discarded.
Anything but a character device at the path (a regular file, a folder, a FIFO, a socket) is
refused before it is opened.

Threads: opened by the main thread at start-up, then owned by the link thread (reopen,
close); nothing here blocks except ``open()`` and the terminal ioctls.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import termios
from functools import cache
from pathlib import Path
from typing import Any

from motorctl.daemon.instance import flock_holder

#: the reopen schedule: the first attempt this long after the loss, then twice as long each
#: time, never more than BACKOFF_MAX_S apart (docs/protocol.md, "A serial device that goes
#: away")
BACKOFF_FIRST_S = 0.05
BACKOFF_MAX_S = 1.0

_FIND = "ls -l /dev/serial/by-id/ /dev/serial* /dev/tty{AMA,S,USB,ACM}*"


class DeviceError(Exception):
    """The device could not be opened; the message names the path and the fix."""

    def __init__(self, message: str, errno_: int | None = None) -> None:
        super().__init__(message)
        self.errno = errno_


def explain(path: str, code: int | None, detail: str) -> str:
    """What a failed open of ``path`` means to a user, and what to do about it."""
    if code in (errno.ENOENT, errno.ENXIO, errno.ENODEV):
        return (
            f"serial device {path} does not exist ({detail}): check the path ({_FIND}), "
            "that the USB adapter is plugged in or the UART enabled; a USB adapter is best "
            "named by its /dev/serial/by-id/ path, which stays the same when it is "
            "plugged back in"
        )
    if code in (errno.EACCES, errno.EPERM):
        return (
            f"no permission to open serial device {path} ({detail}): the user running "
            "motorctld must be in the device's group (ls -l " + path + "; usually "
            "'sudo usermod -aG dialout USER' and log in again; the packaged service's "
            "user motorctl is in dialout)"
        )
    if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY):
        holder = flock_holder(Path(path)) if os.path.exists(path) else None
        who = f" (PID {holder})" if holder is not None else ""
        return (
            f"serial device {path} is held by another process{who}: stop it first "
            "(another motorctld, a getty such as serial-getty@, ModemManager, or a "
            "terminal program)"
        )
    if code == errno.ENOTTY:
        return f"{path} is not a serial device ({detail}): name a tty ({_FIND})"
    return (
        f"cannot open serial device {path}: {detail}; check the path ({_FIND}), that the "
        "UART is enabled, and that the user is in the dialout group"
    )


class Backoff:
    """When to try again: ``first_s`` after the loss, then doubling up to ``max_s``."""

    def __init__(self, first_s: float = BACKOFF_FIRST_S, max_s: float = BACKOFF_MAX_S) -> None:
        self.first_s = first_s
        self.max_s = max_s
        self._next = first_s

    def reset(self) -> None:
        self._next = self.first_s

    def delay(self) -> float:
        """The pause before the next attempt (each call lengthens the following one)."""
        d = self._next
        self._next = min(self.max_s, d * 2.0)
        return d


@cache
def keep_input_serial() -> Any:
    """pyserial's ``Serial`` whose ``open()`` keeps what is in the input buffer.

    pyserial's ``open()`` ends with a ``tcflush(TCIFLUSH)``: the bytes a host sent between
    its device's return and the daemon's reopen would be lost. Only the flush inside
    ``open()`` is skipped; an explicit ``reset_input_buffer()`` afterwards still flushes.
    (tests/daemon/test_serialport.py holds pyserial to this.)"""
    import serial

    class KeepInput(serial.Serial):
        _opening = False

        def open(self) -> None:
            self._opening = True
            try:
                super().open()
            finally:
                self._opening = False

        def _reset_input_buffer(self) -> None:  # pyserial 3.5's open() calls this one
            if not self._opening:
                super()._reset_input_buffer()  # type: ignore[misc]

        def reset_input_buffer(self) -> None:  # and earlier versions' this one
            if not self._opening:
                super().reset_input_buffer()

    return KeepInput


def not_a_device(path: str) -> str | None:
    """What is at ``path`` when it exists and is not a character device (None otherwise):
    such a thing is never opened (a FIFO would block, a file is not a UART)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None  # open() says why
    if stat.S_ISCHR(mode):
        return None
    for test, what in (
        (stat.S_ISREG, "a regular file"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return what
    return "not a character device"


class SerialDevice:
    """A UART (or anything that looks like one) opened by its path, at ``baud``."""

    def __init__(self, path: str, baud: int) -> None:
        self.path = path
        self.baud = baud
        self._port: Any = None  # the pyserial object: it owns the descriptor

    @property
    def fd(self) -> int:
        if self._port is None:
            raise ValueError(f"{self.path} is not open")
        return int(self._port.fileno())

    def open(self) -> int:
        """Open the path (again); the descriptor, non-blocking. Raises :class:`DeviceError`."""
        import serial

        self.close()
        what = not_a_device(self.path)
        if what is not None:
            raise DeviceError(explain(self.path, errno.ENOTTY, what), errno.ENOTTY)
        try:
            port = keep_input_serial()(self.path, self.baud, timeout=0, exclusive=True)
        except serial.SerialException as exc:
            code = exc.errno if isinstance(exc.errno, int) else None
            detail = exc.strerror if code is not None and exc.strerror else str(exc)
            if code is None and "configure port" in str(exc):
                code = errno.ENOTTY  # tcgetattr on something that is not a terminal
            raise DeviceError(explain(self.path, code, detail), code) from exc
        except OSError as exc:  # e.g. ioctls of a device that vanished while being opened
            raise DeviceError(
                explain(self.path, exc.errno, exc.strerror or str(exc)), exc.errno
            ) from exc
        fd = int(port.fileno())
        try:
            attrs = termios.tcgetattr(fd)
            attrs[6][termios.VMIN] = 1  # nothing to read: EAGAIN, not an empty read
            attrs[6][termios.VTIME] = 0
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            os.set_blocking(fd, False)
        except (termios.error, OSError) as exc:
            port.close()
            raise DeviceError(explain(self.path, None, str(exc))) from exc
        self._port = port
        return fd

    def close(self) -> None:
        """Close the descriptor if open (errors of a device already gone are ignored)."""
        port, self._port = self._port, None
        if port is not None:
            # Linux releases the descriptor even when close() reports an error (a hung-up
            # device): never close it a second time, the number may belong to another file.
            with contextlib.suppress(Exception):
                port.close()
