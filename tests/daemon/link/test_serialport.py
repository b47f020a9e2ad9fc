"""The serial device behind --port (daemon.serialport) and the link serving it, in-process.

The "device" is the slave side of a real PTY, reached through a symlink as udev's
/dev/serial/by-id/ names are; the test holds the master (the far end of the wire). Pulling
it out is closing the master and removing the name; plugging it back in is a new PTY at the
same name. The dispatcher behind the link runs on a virtual clock: these tests are about
the descriptor, the bytes and the host's silence.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from motorctl.daemon.link import serialport
from motorctl.daemon.link.devwatch import PathWatch
from motorctl.daemon.link.loop import Link
from motorctl.daemon.link.ports import open_pty
from motorctl.daemon.link.serialport import Backoff, DeviceError, SerialDevice
from motorctl.daemon.link.silence import SilenceWatch
from motorctl.daemon.status.document import summary_line
from motorctl.protocol.codec import (
    GetAbsPos,
    IsReady,
    Response,
)
from tests.support.daemon_proc import DaemonProcess
from tests.support.frames import OPTS, answers, frame
from tests.support.fsutil import need_checkout_open_to_others
from tests.support.inprocess import TWO_MOTORS, build_daemon
from tests.support.wait import until

DEADLINE_S = 20.0  # for conditions that take milliseconds, on a loaded 2-core machine


class Adapter:
    """A serial adapter at ``path``: a PTY whose slave ``path`` names; we hold the master."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.master, slave = os.openpty()
        name = os.ttyname(slave)
        os.close(slave)
        path.unlink(missing_ok=True)
        path.symlink_to(name)

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def responses(self, n: int) -> list[Response]:
        out = bytearray()
        end = time.monotonic() + DEADLINE_S
        while len(out) < 5 * n:
            left = end - time.monotonic()
            assert left > 0 and select.select([self.master], [], [], left)[0], (
                f"got {len(out) // 5} of {n} responses"
            )
            out += os.read(self.master, 5 * n - len(out))
        return answers(out)

    def nothing_within(self, seconds: float) -> bool:
        return not select.select([self.master], [], [], seconds)[0]

    def unplug(self) -> None:
        """Its name first, then its PTY: a name left to a gone /dev/pts/N names the next
        PTY made with that number (tests/docs/test_messages.py, ``Session.unplug``)."""
        self.path.unlink()
        os.close(self.master)


class FailsFirst(SerialDevice):
    """A device whose reopen fails with ``errnos`` first (say, udev has not yet given the
    node its group): pyserial's own exception, as it raises it."""

    def __init__(self, path: str, errnos: list[int]) -> None:
        super().__init__(path, 115200)
        self.errnos = errnos
        self.opened = 0

    def open(self) -> int:
        self.opened += 1
        if self.opened > 1 and self.errnos:
            code = self.errnos.pop(0)
            raise DeviceError(f"cannot open {self.path}: {os.strerror(code)}", code)
        return super().open()


class DeviceServed:
    """A Link serving a SerialDevice on a thread, with a daemon on a virtual clock behind."""

    def __init__(self, tmp: Path, device: SerialDevice, slow: bool = False, **kw: Any) -> None:
        """``slow``: a backoff of 60 s, so that only ``notice`` can find the device back
        within a test's deadline."""
        self.daemon = build_daemon(TWO_MOTORS, tmp / "state")
        self.device = device
        self.link = Link(
            device.open(),
            self.daemon.dispatcher,
            OPTS,
            0.010,
            16,
            device=device,
            backoff=Backoff(60.0, 60.0) if slow else Backoff(0.005, 0.02),
            **kw,
        )
        self.thread = threading.Thread(target=self.link.serve, name="link", daemon=True)
        self.thread.start()

    def counters(self) -> dict[str, Any]:
        counters = self.link.status()["counters"]
        assert isinstance(counters, dict)
        return counters

    def close(self) -> None:
        if not self.thread.is_alive():
            return
        self.link.stop()
        self.thread.join(DEADLINE_S)
        assert not self.thread.is_alive(), "the link thread did not stop"
        self.link.close()
        self.device.close()


@pytest.fixture
def names(tmp_path: Path) -> tuple[Path, Path]:
    """The device's kernel-like name and a by-id symlink to it."""
    (tmp_path / "by-id").mkdir()
    by_id = tmp_path / "by-id" / "usb-test-if00-port0"
    by_id.symlink_to(tmp_path / "ttyUSB0")
    return tmp_path / "ttyUSB0", by_id


@pytest.fixture
def adapter(names: tuple[Path, Path]) -> Iterator[Adapter]:
    a = Adapter(names[0])
    yield a
    if a.path.exists():
        os.close(a.master)


def test_unplugged_and_plugged_back_in_it_is_served_again(
    tmp_path: Path, names: tuple[Path, Path], adapter: Adapter, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.link")
    s = DeviceServed(tmp_path, SerialDevice(str(names[1]), 115200))
    try:
        adapter.write(frame(IsReady(0)))
        assert adapter.responses(1) == [Response.boolean(True)]
        adapter.write(frame(GetAbsPos(0))[:4])  # half a frame, then pulled out
        until("the 4 bytes", lambda: s.counters()["bytes_in"] == 14, detail=s.counters)
        adapter.unplug()
        # the dead descriptor is closed (the link thread marks the peer gone first)
        until(
            "the loss",
            lambda: s.link.status()["peer"] == "gone" and s.link.fd == -1,
            detail=s.counters,
        )
        until(
            "attempts to reopen it", lambda: s.counters()["reopen_attempts"] >= 3, detail=s.counters
        )
        assert s.counters()["device_reopened"] == 0
        again = Adapter(names[0])  # back, as another tty behind the same names
        try:
            # the device's watch counts the reopen before the link thread takes its descriptor
            until(
                "the reopen",
                lambda: s.counters()["device_reopened"] == 1 and s.link.status()["peer"] == "open",
                detail=s.counters,
            )
            again.write(frame(IsReady(1)))
            assert again.responses(1) == [Response.boolean(True)]  # its own answer only
            assert again.nothing_within(0.05)
            c = s.counters()
            assert c["device_lost"] == 1
            assert (c["hangup_partial_bytes"], c["gap_discards"]) in ((4, 0), (0, 1))
        finally:
            s.close()
            again.unplug()
    finally:
        s.close()
    lost = [r for r in caplog.records if "is gone" in r.getMessage()]
    assert len(lost) == 1 and lost[0].levelno == logging.WARNING  # once, not per attempt
    assert str(names[1]) in lost[0].getMessage()
    assert sum("is back after" in r.getMessage() for r in caplog.records) == 1
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING and r is not lost[0]]


def test_a_device_back_but_not_yet_usable_is_named_once_and_retried(
    tmp_path: Path, names: tuple[Path, Path], adapter: Adapter, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "motorctl.link")
    device = FailsFirst(str(names[1]), [errno.EACCES, errno.EACCES, errno.EBUSY])
    s = DeviceServed(tmp_path, device)
    again: Adapter | None = None
    try:
        adapter.unplug()
        until("the loss", lambda: s.link.status()["peer"] == "gone", detail=s.counters)
        again = Adapter(names[0])
        until("the reopen", lambda: s.counters()["device_reopened"] == 1, detail=s.counters)
        again.write(frame(IsReady(0)))
        assert again.responses(1) == [Response.boolean(True)]
        assert device.opened == 5  # at start, 3 refused, then it
    finally:
        s.close()
        if again is not None:
            again.unplug()
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 3, warnings  # the loss; EACCES once; EBUSY once
    assert os.strerror(errno.EACCES) in warnings[1]
    assert os.strerror(errno.EBUSY) in warnings[2]


def test_a_read_with_nothing_to_read_is_not_a_hang_up(adapter: Adapter) -> None:
    """pyserial leaves VMIN = 0, so an empty read would look like a device that hung up
    (the daemon took every gap for "the host closed the port"); VMIN = 1: EAGAIN."""
    device = SerialDevice(str(adapter.path), 115200)
    fd = device.open()
    try:
        with pytest.raises(BlockingIOError):
            os.read(fd, 10)
        adapter.write(b"xy")
        until("the bytes", lambda: select.select([fd], [], [], 0)[0])
        assert os.read(fd, 10) == b"xy"
    finally:
        device.close()


def test_the_host_keeps_the_link_alive_with_any_bytes(tmp_path: Path) -> None:
    """The shell tells the watch of every read, even of bytes that never make a good frame;
    it checks the silence on the link's clock (injected: it moves only when told)."""
    now = [0.0]
    acted: list[float] = []

    def act(t: float) -> list[str]:
        acted.append(t)
        return ["motor 0 (a)"]

    daemon = build_daemon(TWO_MOTORS, tmp_path / "state")
    fd, name = open_pty(tmp_path / "pty")
    link = Link(
        fd,
        daemon.dispatcher,
        OPTS,
        0.010,
        16,
        clock=lambda: now[0],
        watch=SilenceWatch(0.5, act, 0.0),
    )
    thread = threading.Thread(target=link.serve, name="link", daemon=True)
    thread.start()
    host = os.open(name, os.O_RDWR | os.O_NOCTTY)

    def counters() -> dict[str, Any]:
        c = link.status()["counters"]
        assert isinstance(c, dict)
        return c

    def at(t: float) -> None:
        """Move the link's clock to ``t`` and wait until a whole turn of the loop saw it
        (the turn under way may have read the clock before)."""
        now[0] = t
        for _ in range(2):
            turns = link.turns
            link.poke()

            def turned(t: int = turns) -> bool:
                return link.turns > t

            until("a turn", turned, detail=counters)

    try:
        good = frame(GetAbsPos(0))
        at(0.4)
        os.write(host, good[:9] + bytes([good[9] ^ 0xFF]))  # fails its checksum
        until("the bad frame", lambda: counters()["checksum_errors"] == 1, detail=counters)
        at(0.8)
        os.write(host, good[:3])  # three bytes of a frame that never completes
        until("the bytes", lambda: counters()["bytes_in"] == 13, detail=counters)
        at(1.25)
        assert acted == []
        at(1.35)
        assert acted == [1.35]
        at(5.0)
        assert acted == [1.35]  # once per silence
        assert counters()["link_timeouts"] == 1 and counters()["link_timeout_stops"] == 1
    finally:
        link.stop()
        thread.join(DEADLINE_S)
        link.close()
        os.close(host)
        os.close(fd)


# -- the device's return, noticed at once, nothing the host sent lost -------------------------
class Raw:
    """A serial adapter's tty made, and written to from the far end, before its name
    exists: the bytes wait in the tty for whoever opens it (as socat's PTYs made again, or
    a USB adapter that buffers what came before the daemon's open)."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)  # as socat's pty,raw,echo=0: bytes are taken as they are
        self.name = os.ttyname(slave)
        os.close(slave)

    def responses(self, n: int) -> list[Response]:
        """Once the daemon has the tty open (until then the master reads EIO)."""
        return Adapter.responses(self, n)  # type: ignore[arg-type]

    def close(self) -> None:
        os.close(self.master)


def test_bytes_sent_before_the_device_is_opened_again_are_read(
    tmp_path: Path, names: tuple[Path, Path], adapter: Adapter
) -> None:
    """The host writes as soon as its device is back, before the daemon has opened it:
    pyserial's open() would flush those bytes (the host would wait for answers that never
    come); the daemon's keeps them. And its return is noticed through the folder's events,
    not the backoff (60 s here: a reopen by the schedule would fail the deadline)."""
    s = DeviceServed(
        tmp_path,
        SerialDevice(str(names[1]), 115200),
        notice=PathWatch(str(names[1])),
        slow=True,
    )
    raw: Raw | None = None
    try:
        adapter.unplug()
        # (counted once the path is watched: it may come back from then on)
        until("the loss", lambda: s.counters()["device_lost"] == 1, detail=s.counters)
        raw = Raw()
        os.write(raw.master, frame(IsReady(0), GetAbsPos(1)))  # the new session's frames
        names[0].symlink_to(raw.name)  # only now can the daemon open it
        until("the reopen", lambda: s.counters()["device_reopened"] == 1, detail=s.counters)
        assert raw.responses(2) == [Response.boolean(True), Response.position(0)]
        c = s.counters()
        assert c["device_reopened"] == 1 and c["reopen_attempts"] <= 3, c
    finally:
        s.close()
        if raw is not None:
            raw.close()


def test_a_device_whose_folder_went_too_is_noticed_when_both_are_back(tmp_path: Path) -> None:
    """udev removes /dev/serial/by-id/ with the last adapter: the daemon watches the
    nearest folder that exists for the missing one's name, then the new folder for its
    link; the backoff (60 s) plays no part."""
    by_id = tmp_path / "serial" / "by-id"
    by_id.mkdir(parents=True)
    path = by_id / "usb-test-if00-port0"
    first = Raw()
    path.symlink_to(first.name)
    s = DeviceServed(
        tmp_path, SerialDevice(str(path), 115200), notice=PathWatch(str(path)), slow=True
    )
    second: Raw | None = None
    try:
        first.close()
        path.unlink()
        shutil.rmtree(tmp_path / "serial")
        until("the loss", lambda: s.counters()["device_lost"] == 1, detail=s.counters)
        second = Raw()
        by_id.mkdir(parents=True)
        path.symlink_to(second.name)
        until("the reopen", lambda: s.counters()["device_reopened"] == 1, detail=s.counters)
        os.write(second.master, frame(IsReady(1)))
        assert second.responses(1) == [Response.boolean(True)]
    finally:
        s.close()
        if second is not None:
            second.close()


def test_motorctld_waits_for_a_device_not_there_at_start(tmp_path: Path) -> None:
    """Ready at once, saying what it waits for; served as soon as the device appears; the
    log says each once."""
    (tmp_path / "by-id").mkdir()
    path = tmp_path / "by-id" / "usb-late-if00"
    d = DaemonProcess(tmp_path, TWO_MOTORS, port=str(path)).start()
    raw: Raw | None = None
    try:
        assert "not there yet" in d.ready_line
        link = d.status()["link"]
        assert link["peer"] == "waiting" and link["device"] == str(path)
        assert "WAITING FOR SERIAL DEVICE" in summary_line(d.status())
        raw = Raw()
        os.write(raw.master, frame(IsReady(0)))  # sent before the device is there
        path.symlink_to(raw.name)
        until("the device served", lambda: d.status()["link"]["peer"] == "open")
        assert raw.responses(1) == [Response.boolean(True)]
    finally:
        d.close()
        if raw is not None:
            raw.close()
    err = d.stderr()
    assert err.count("is not there: serving it as soon as it appears") == 1, err
    assert err.count("is there after") == 1, err
    assert "Traceback" not in err


# -- what a user is told ----------------------------------------------------------------------
def test_a_missing_device_names_the_path_and_where_to_look(tmp_path: Path) -> None:
    path = str(tmp_path / "ttyUSB7")
    with pytest.raises(DeviceError) as exc:
        SerialDevice(path, 115200).open()
    msg = str(exc.value)
    assert exc.value.errno == errno.ENOENT
    assert f"serial device {path} does not exist" in msg
    assert "/dev/serial/by-id/" in msg and "plugged in" in msg


def test_something_that_is_not_a_tty_is_named(tmp_path: Path) -> None:
    path = tmp_path / "file"
    path.write_text("")
    with pytest.raises(DeviceError) as exc:
        SerialDevice(str(path), 115200).open()
    assert f"{path} is not a serial device" in str(exc.value)


def test_no_permission_names_the_group(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests run as root here, where no device refuses: pyserial's own exception."""

    def refuse(port: str, *args: Any, **kw: Any) -> None:
        raise serial.SerialException(
            errno.EACCES, f"could not open port {port}: [Errno 13] Permission denied: '{port}'"
        )

    monkeypatch.setattr(serialport, "keep_input_serial", lambda: refuse)
    with pytest.raises(DeviceError) as exc:
        SerialDevice("/dev/ttyUSB0", 115200).open()
    msg = str(exc.value)
    assert "no permission to open serial device /dev/ttyUSB0" in msg
    assert "dialout" in msg and "usermod" in msg


def test_a_held_device_names_its_holder(adapter: Adapter) -> None:
    holder = os.open(adapter.path, os.O_RDWR | os.O_NOCTTY)
    fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what pyserial's exclusive=True takes
    try:
        with pytest.raises(DeviceError) as exc:
            SerialDevice(str(adapter.path), 115200).open()
    finally:
        os.close(holder)
    assert f"serial device {adapter.path} is held by another process (PID {os.getpid()})" in str(
        exc.value
    )


def _motorctld(args: list[str], *, as_nobody: bool = False) -> subprocess.CompletedProcess[str]:
    """``motorctld ARGS`` as a user runs it (``as_nobody``: as user nobody, when root)."""
    cmd = [sys.executable, "-m", "motorctl.daemon.start.main", *args]
    if as_nobody:
        cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=DEADLINE_S)


def _files(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file of ``folder`` but the lock, with its bytes and modification time."""
    return {
        f.name: (f.read_bytes(), f.stat().st_mtime_ns)
        for f in sorted(folder.iterdir())
        if f.name != "motorctld.lock"
    }


@pytest.mark.parametrize("what", ["a regular file", "/dev/null", "no permission"])
def test_a_device_that_cannot_be_used_stops_the_start_before_the_state(
    tmp_path: Path, what: str, request: pytest.FixtureRequest
) -> None:
    """A --port device that is there but cannot be used (not a tty, no permission) is
    named with its fix, exit 1, and the state is left as it was: not restored, not set
    aside, not written again (a state file no daemon could take stands in for any)."""
    as_nobody = what == "no permission" and os.geteuid() == 0
    if as_nobody:  # root opens anything: the daemon runs as user nobody, in a folder it
        # can reach (pytest's are its owner's only)
        need_checkout_open_to_others()
        tmp_path = Path(tempfile.mkdtemp(prefix="motorctl-test-"))
        tmp_path.chmod(0o755)
        request.addfinalizer(lambda: shutil.rmtree(tmp_path))
    state = tmp_path / "state"
    state.mkdir()
    (state / "state.json").write_text("a state file the daemon would set aside\n")
    if as_nobody:
        os.chown(state, 65534, 65534)
        os.chown(state / "state.json", 65534, 65534)
    before = _files(state)
    master = -1
    if what == "a regular file":
        device = tmp_path / "ttyUSB0"
        device.write_text("")
        expected = f"{device} is not a serial device (a regular file)"
    elif what == "/dev/null":
        device = Path("/dev/null")
        expected = "/dev/null is not a serial device"
    else:
        master, slave = os.openpty()
        device = Path(os.ttyname(slave))
        os.close(slave)
        os.chmod(device, 0o600 if as_nobody else 0)  # not for the daemon's user
        expected = f"no permission to open serial device {device}"
    try:
        out = _motorctld(["--port", str(device), "--state-dir", str(state)], as_nobody=as_nobody)
    finally:
        if master >= 0:
            os.close(master)
    assert out.returncode == 1, out.stderr
    assert expected in out.stderr, out.stderr
    assert "Traceback" not in out.stderr
    assert _files(state) == before  # not restored, not set aside, not rewritten


def test_backoff_doubles_up_to_its_limit() -> None:
    b = Backoff()
    assert [b.delay() for _ in range(8)] == [0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0, 1.0]
    b.reset()
    assert b.delay() == 0.05
