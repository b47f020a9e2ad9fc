"""Where the daemon serves: a new PTY (``--pty``) or a UART (``--port``), opened for the link.

Threads: the main thread, at start-up (daemon/main.py); the descriptors it returns then
belong to the link (daemon/link.py).
"""

from __future__ import annotations

import os
import termios
import tty
from pathlib import Path

from motorctl.daemon.assemble import StartupError
from motorctl.daemon.serialport import DeviceError, SerialDevice


def open_pty(path: Path) -> tuple[int, str]:
    """A new PTY in raw mode; ``path`` becomes a symlink to its slave. Returns the master fd
    and the slave's name.

    The daemon does not keep the slave open: the master then sees the host close the port
    (POLLHUP, EIO) and drops what was meant for it, as a UART's bytes to a closed port are
    lost, instead of leaving stale responses for the next host. The raw mode stays set while
    the master is open.

    The slave is mode 0660 with the daemon's group (the ``motorctl`` group under systemd):
    only that group's members may drive the motors."""
    if (path.exists() or path.is_symlink()) and not path.is_symlink():
        raise StartupError(
            f"{path} exists and is not a symlink; remove it or choose another --pty path"
        )
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


def open_uart(device: str, baud: int) -> tuple[SerialDevice, int]:
    """The UART (or any serial device) at ``device``, opened by that path so that it can be
    opened again by it when it goes away and comes back (daemon.serialport)."""
    uart = SerialDevice(device, baud)
    try:
        return uart, uart.open()
    except DeviceError as exc:
        raise StartupError(str(exc)) from exc
