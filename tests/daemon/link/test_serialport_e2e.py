"""End to end: a serial device that goes away and comes back, and the host's silence.

motorctld runs as a real process. The serial device is one side of a socat PTY pair (the
host uses the other), torn down mid-move and made again at the same paths, as a USB adapter
unplugged and plugged back in; the daemon is given a symlink to socat's symlink, as udev's
/dev/serial/by-id/ names are. Every wait has a deadline and fails naming what it waited for.
"""

from __future__ import annotations

import contextlib
import os
import select
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.protocol.codec import (
    CodecOptions,
    Command,
    ErrorCode,
    GetAbsPos,
    IsReady,
    MoveTo,
    Response,
    WaitMoved,
    encode_command,
)
from tests.support.daemon_proc import DaemonProcess
from tests.support.frames import answers
from tests.support.socat import PtyPair, needs_socat
from tests.support.wait import until

E = ErrorCode
OPTS = CodecOptions()
CONFIG = """
[[motors]]
name = "a"
default_speed = 400
  [motors.mock]
  endstop_max = 8000000
[[motors]]
name = "b"
"""


@pytest.fixture
def pair(tmp_path: Path) -> Iterator[PtyPair]:
    p = PtyPair(tmp_path / "ttyUSB", tmp_path / "host", tmp_path / "socat.log")
    yield p
    p.stop()


def by_id(tmp_path: Path, target: Path) -> Path:
    """A stable name for the device, as udev's /dev/serial/by-id/usb-...: a symlink."""
    (tmp_path / "by-id").mkdir()
    link = tmp_path / "by-id" / "usb-motorctl_test-if00-port0"
    link.symlink_to(target)
    return link


def link_status(d: DaemonProcess) -> dict[str, Any]:
    link = d.status()["link"]
    assert isinstance(link, dict)
    return link


def motor(d: DaemonProcess, index: int) -> dict[str, Any]:
    m = d.status()["motors"][index]
    assert isinstance(m, dict)
    return m


@needs_socat
def test_a_serial_device_torn_down_mid_move_is_reopened_by_its_path(
    tmp_path: Path, pair: PtyPair
) -> None:
    pair.start()
    d = DaemonProcess(tmp_path, CONFIG, port=str(by_id(tmp_path, pair.device))).start()
    host: Client | None = None
    try:
        with Client(str(pair.host), timeout=10) as c:
            c.move(0, True)
            assert not c.is_ready(0)
            c.save_waypoint(1)  # state that must survive: a waypoint of the idle motor
            before = c.position(0)
        pair.stop()  # unplugged, mid-move
        until("the daemon to notice the device is gone", lambda: link_status(d)["peer"] == "gone")
        assert motor(d, 0)["state"] == "running"  # nothing stops: no [link] timeout_ms
        # (the device is noticed back at once: it moved on before it is plugged in again)
        until("motor 0 to move on meanwhile", lambda: motor(d, 0)["position"] > before)
        pair.start()  # plugged back in, the same names
        until("the daemon to reopen the device", lambda: link_status(d)["peer"] == "open")
        # open until the daemon has stopped: socat ends the pair when the host closes it
        host = c = Client(str(pair.host), timeout=10)
        assert c.position(0) > before  # it kept moving, and counting
        assert not c.is_ready(0)
        c.stop(0)
        until("motor 0 to stop", lambda: c.is_ready(0))
        c.move_to_waypoint(1, 0)  # the waypoint survived
        c.wait_moved(1, 10000)
        counters = link_status(d)["counters"]
        assert counters["device_lost"] == 1
        assert counters["device_reopened"] == 1
        assert counters["reopen_attempts"] >= 1
    finally:
        d.close()
        if host is not None:
            host.close()
    err = d.stderr()
    assert err.count("is gone") == 1, err  # logged once, however many attempts it took
    assert err.count("is back after") == 1, err
    assert "the host closed the port" not in err, err
    assert "Traceback" not in err


@needs_socat
def test_the_silence_of_a_device_that_is_gone_stops_the_motors(
    tmp_path: Path, pair: PtyPair
) -> None:
    """[link] timeout_ms applies while the device is gone: the motor stops and latches E4,
    which the host finds when the device is back, until its StopMove."""
    pair.start()
    config = CONFIG + '[link]\ntimeout_ms = 200\ntimeout_action = "hard"\n'
    d = DaemonProcess(tmp_path, config, port=str(pair.device)).start()
    try:
        with Client(str(pair.host), timeout=10) as c:
            c.move(0, True)  # nothing more: a check here could race the 200 ms
        pair.stop()
        until("the link timeout to stop motor 0", lambda: motor(d, 0)["state"] == "fault")
        assert motor(d, 0)["fault"].startswith("link timeout")
        assert motor(d, 1)["state"] == "idle" and motor(d, 1)["fault"] is None
        pair.start()
        until("the daemon to reopen the device", lambda: link_status(d)["peer"] == "open")
        with Client(str(pair.host), timeout=10) as c:
            with pytest.raises(DeviceError) as exc:
                c.is_ready(0)
            assert exc.value.code == E.MOTOR_ERROR
            assert c.is_ready(1)  # a motor at rest was not touched
            c.stop(0)  # clears it
            assert c.is_ready(0)
        assert link_status(d)["counters"]["link_timeouts"] == 1
    finally:
        d.close()
    assert "no byte from the host for" in d.stderr()


def test_the_hosts_silence_on_a_pty_stops_a_move_that_decelerates(tmp_path: Path) -> None:
    """A real daemon on its PTY: the host goes quiet mid-move; the motor ramps down and
    latches E4 (IsReady and WaitMoved included) until a StopMove, then moves again."""
    config = CONFIG + "[link]\ntimeout_ms = 150\n"  # timeout_action: decelerate, the default
    d = DaemonProcess(tmp_path, config).start()
    try:
        with d.client(timeout=10) as c:
            c.move(0, True)  # nothing more: a check here could race the 150 ms
            # silence: only the status socket is read (it is not the link)
            until("motor 0 to stop and latch the fault", lambda: motor(d, 0)["state"] == "fault")
            m = motor(d, 0)
            assert m["fault"] == "link timeout: no byte from the host for 150 ms"
            assert not m["position_lost"]
            for call in (
                lambda: c.is_ready(0),
                lambda: c.wait_moved(0, 100),
                lambda: c.move(0, True),
            ):
                with pytest.raises(DeviceError) as exc:
                    call()
                assert exc.value.code == E.MOTOR_ERROR
            c.stop(0)
            assert c.is_ready(0)
            # moves again; the WaitMoved in the same write: the host waits, it is not silent
            target = c.position(0) + 40
            c.send_bytes(
                encode_command(MoveTo(0, True, target, 0, 0, 0), OPTS)
                + encode_command(WaitMoved(0, 10000), OPTS)
            )
            assert [c.read_response().ack for _ in range(2)] == [True, True]
            assert c.position(0) == target
        counters = link_status(d)["counters"]
        assert counters["link_timeouts"] == 1  # the silence after the last answer: all idle
        assert counters["link_timeout_stops"] == 1
    finally:
        d.close()
    err = d.stderr()
    assert "no byte from the host for" in err and "motor 0 (a)" in err, err
    assert "fault latched: link timeout" in err, err


class RawHost:
    """The host's side of the socat pair, opened as a host program opens a serial port,
    without a client library: it can close the port without reading."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def write(self, *cmds: Command) -> None:
        os.write(self.fd, b"".join(encode_command(c, OPTS) for c in cmds))

    def responses(self, n: int, timeout: float = 20.0) -> list[Response]:
        out = bytearray()
        end = time.monotonic() + timeout
        while len(out) < 5 * n:
            left = end - time.monotonic()
            assert left > 0 and select.select([self.fd], [], [], left)[0], (
                f"got {len(out) // 5} of {n} responses"
            )
            with contextlib.suppress(BlockingIOError):
                out += os.read(self.fd, 5 * n - len(out))
        return answers(bytes(out))

    def nothing_within(self, seconds: float) -> bool:
        return not select.select([self.fd], [], [], seconds)[0]

    def close(self) -> None:
        os.close(self.fd)


@needs_socat
def test_a_new_host_after_the_device_came_back_reads_only_its_own_answers(
    tmp_path: Path, pair: PtyPair
) -> None:
    """Issue 22's scenario over --port: MoveTo 0 -> 6000 at 1000 step/s, WaitMoved(0, 30 s)
    and GetAbsPos(2), then the host closes without reading, the device hangs up (socat
    torn down) and comes back (made again); the new host's IsReady(1) is answered at
    once with its own answer, and a GetAbsPos after it reads a position, not an old
    answer. The host writes as soon as its port is there: nothing it sends is lost."""
    pair.start()
    d = DaemonProcess(tmp_path, CONFIG + '[[motors]]\nname = "c"\n', port=str(pair.device))
    d.start()
    host: RawHost | None = None
    try:
        old = RawHost(pair.host)
        old.write(MoveTo(0, True, 6000, 250, 0, 0))  # SPEED 250 x 4 = 1000 step/s
        assert old.responses(1)[0].ack
        old.write(WaitMoved(0, 30_000), GetAbsPos(2))
        until("the WaitMoved held, GetAbsPos kept", lambda: link_status(d)["held"] == 1)
        old.close()
        pair.stop()  # the device hangs up (socat goes on when only the host closes)
        until("the device's loss", lambda: link_status(d)["counters"]["device_lost"] == 1)
        pair.start()  # the same names, a new device
        host = RawHost(pair.host)
        host.write(IsReady(1))  # at once: the daemon may not have opened the device yet
        assert host.responses(1) == [Response.boolean(True)]
        assert motor(d, 0)["state"] != "idle"  # answered long before the move ends
        host.write(GetAbsPos(0))
        position = host.responses(1)[0].as_position
        assert 0 <= position <= motor(d, 0)["position"] < 6000  # the position, still moving
        assert host.nothing_within(0.2)
        counters = link_status(d)["counters"]
        assert counters["responses_dropped_wait"] == 1
        assert counters["responses_dropped_held"] == 1
        assert counters["held_discarded"] == 1
    finally:
        d.close()
        if host is not None:
            host.close()
    err = d.stderr()
    assert "a held WaitMoved's answer" in err, err
    assert "Traceback" not in err
