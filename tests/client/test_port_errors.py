"""Why motorctl cannot open its port (client/port_errors.py), from pyserial's real failures
on real paths: a missing port (and a daemon's link left behind), something that is no serial
device, a device that is not a terminal. Permission and busy need another user: the CLI as a
process, as user nobody, in test_cli_e2e.py."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import serial

from motorctl.client.port_errors import DEFAULT_PORT, not_a_port, open_error
from tests.support import REPO


def failed_open(path: str, baud: int = 115200) -> BaseException:
    try:
        serial.Serial(path, baud, timeout=0).close()
    except (serial.SerialException, OSError, ValueError) as exc:
        return exc
    raise AssertionError(f"{path} opened")


def test_the_default_port_is_the_services() -> None:
    text = (REPO / "systemd" / "motorctld.default").read_text()
    served = re.findall(r'^MOTORCTLD_SERVE="--pty (\S+)"', text, re.M)
    assert served == [DEFAULT_PORT]


def test_a_missing_port_asks_whether_motorctld_runs(tmp_path: Path) -> None:
    path = str(tmp_path / "ttyNOPE")
    assert not_a_port(path) is None  # the open says why
    assert open_error(path, failed_open(path), 115200) == (
        f"cannot open {path}: no such file (is motorctld running? its default port is "
        "/run/motorctl/motorctl.pty)"
    )


def test_the_link_a_daemon_left_names_where_it_pointed(tmp_path: Path) -> None:
    """motorctld killed with SIGKILL leaves its PTY's link to a /dev/pts/N that is gone."""
    link = tmp_path / "motorctl.pty"
    link.symlink_to("/dev/pts/4242")
    assert open_error(str(link), failed_open(str(link)), 115200) == (
        f"cannot open {link}: no such file: it is a link to /dev/pts/4242, which is gone "
        "(is motorctld running? its default port is /run/motorctl/motorctl.pty)"
    )


def test_what_is_no_character_device_is_never_opened(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # an open would wait for a writer
    assert not_a_port(str(fifo)) == f"{fifo}: not a serial device (a FIFO)"
    assert not_a_port("/etc/passwd") == "/etc/passwd: not a serial device (a regular file)"
    assert not_a_port(str(tmp_path)) == f"{tmp_path}: not a serial device (a folder)"
    assert not_a_port("/dev/null") is None  # a character device: tried


def test_a_character_device_that_is_not_a_terminal() -> None:
    assert open_error("/dev/null", failed_open("/dev/null"), 115200) == (
        "/dev/null: not a serial device (a character device that is not a terminal)"
    )


def test_a_rate_the_driver_refuses_says_so() -> None:
    """pyserial's own words when the kernel's custom-rate ioctl fails (a PTY takes any rate,
    so this one is pyserial's exception as it raises it)."""
    exc = ValueError("Failed to set custom baud rate (12345): [Errno 22] Invalid argument")
    assert open_error("/dev/ttyUSB0", exc, 12345) == (
        "cannot open /dev/ttyUSB0: its driver refuses 12345 baud, which is not one of the "
        "rates termios names (9600, 19200, 38400, 57600, 115200, 230400, ...)"
    )


@pytest.mark.parametrize("errno_", [13, 16])
def test_permission_and_busy_are_told_apart(errno_: int, tmp_path: Path) -> None:
    """pyserial's exception as it raises it for EACCES and EBUSY (the real ones: the CLI
    as user nobody, test_cli_e2e.py)."""
    dev = tmp_path / "ttyX"
    dev.write_text("")
    exc = serial.SerialException(errno_, f"could not open port {dev}: [Errno {errno_}] ...")
    text = open_error(str(dev), exc, 115200)
    if errno_ == 13:
        assert text.startswith(f"cannot open {dev}: permission denied: it is not open to ")
        assert "join the group with 'sudo adduser $USER root' and log in again" in text
    else:
        assert text.startswith(f"cannot open {dev}: busy: another program has it open")
