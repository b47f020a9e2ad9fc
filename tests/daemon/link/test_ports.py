"""The PTY's slave side as the link holds it (daemon/link/ports.py, PtySlave): what a host
that went left unread in the slave's input is read out, counted and flushed; a session
that was written nothing is not looked at. A real PTY, as the daemon makes it."""

from __future__ import annotations

import os
import select
import termios
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.link.ports import PtySlave, open_pty


@pytest.fixture
def pty(tmp_path: Path) -> Iterator[tuple[int, PtySlave]]:
    master, name = open_pty(tmp_path / "pty")
    slave = PtySlave(master, name)
    try:
        yield master, slave
    finally:
        slave.close()
        os.close(master)


def _next_host_reads(slave: PtySlave) -> bytes:
    """What a host that opens the slave now finds in its input (waiting briefly for the
    kernel to move what the master wrote last)."""
    fd = os.open(slave.name, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        if not select.select([fd], [], [], 0.2)[0]:
            return b""
        return os.read(fd, 4096)
    finally:
        os.close(fd)


def test_what_the_last_host_left_unread_is_counted_and_flushed(
    pty: tuple[int, PtySlave],
) -> None:
    master, slave = pty
    os.write(master, b"\x01" * 15)  # three answers nobody read; the last written just now
    assert slave.hold() == 15
    assert slave.held
    assert _next_host_reads(slave) == b""


def test_a_session_written_nothing_is_not_looked_at(pty: tuple[int, PtySlave]) -> None:
    """``answered=False``: the link wrote nothing since the session began, so nothing of
    its can be in the slave's input; the slave is held without a read (what the test wrote
    through the master behind the link's back stays there: nothing was looked at)."""
    master, slave = pty
    os.write(master, b"\x02" * 5)
    assert slave.hold(answered=False) == 0
    assert slave.held
    assert _next_host_reads(slave) == b"\x02" * 5


def test_a_partial_line_left_in_a_canonical_mode_is_flushed(pty: tuple[int, PtySlave]) -> None:
    """A host that left the slave in a canonical mode: a whole line is read out and counted;
    the partial line after it cannot be read, and the kernel does not count it (FIONREAD
    counts whole lines): flushed, uncounted."""
    master, slave = pty
    host = os.open(slave.name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        attrs = termios.tcgetattr(host)
        attrs[3] |= termios.ICANON
        termios.tcsetattr(host, termios.TCSANOW, attrs)
    finally:
        os.close(host)
    os.write(master, b"\x05\x01\n\x07\x07")
    assert slave.hold() == 3
    slave.release()
    host = os.open(slave.name, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:  # out of the canonical mode a partial line could be read: there is none
        attrs = termios.tcgetattr(host)
        attrs[3] &= ~termios.ICANON
        termios.tcsetattr(host, termios.TCSANOW, attrs)
        assert not select.select([host], [], [], 0.1)[0]
    finally:
        os.close(host)
