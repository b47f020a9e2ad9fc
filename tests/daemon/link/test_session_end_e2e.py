"""End to end: what an ended session's host wrote and motorctld had not read goes with the
session (daemon/link/session_end.py), motorctld as a real process, hosts through pyserial.

The scenario of issue 32: a host writes 8,500 whole GetAbsPos(2) frames in one write and
never reads; the daemon stops reading once 4096 answers are owed (back pressure,
docs/protocol.md) and the rest waits in the kernel; then the host closes the port. Once the
daemon has counted the close, a new host opens the port, flushes its input and sends
IsReady(1): the answer it reads is its own, and the next one too.

On the daemon's PTY the kernel keeps what the old host wrote for the master after the host's
close (it discards nothing at a close, nor at a new host's open or input flush): the daemon
reads it out at the session's end and drops it, carrying out the StopMove among it. On a
serial device (a socat pair, torn down and made again as a USB adapter unplugged and plugged
back in) what was on its way goes with the device; the new host's answers are its own
there too."""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import serial

from motorctl.client.client import Client, LinkError
from motorctl.protocol.codec import GetAbsPos, IsReady, Response, StopMove, encode_response
from tests.support.daemon_proc import DaemonProcess
from tests.support.frames import OPTS, frame
from tests.support.socat import PtyPair, needs_socat
from tests.support.wait import WAIT_S, until

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

FRAMES = 8500
#: motor 2's position: the old host's GetAbsPos(2) answers are told from the new host's
OLD_POSITION = 1234


class Writer(threading.Thread):
    """A host's one blocking write (pyserial's, no write timeout), on a thread of its own."""

    def __init__(self, port: serial.Serial, data: bytes) -> None:
        super().__init__(daemon=True)
        self.port, self.data = port, data
        self.done = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.port.write(self.data)
        except (serial.SerialException, OSError, TypeError) as exc:  # its port went
            self.error = exc
        finally:
            self.done.set()


def counters(d: DaemonProcess) -> dict[str, int]:
    link = d.status()["link"]
    assert isinstance(link, dict)
    out = link["counters"]
    assert isinstance(out, dict)
    return out


def motor(d: DaemonProcess, index: int) -> dict[str, Any]:
    m = d.status()["motors"][index]
    assert isinstance(m, dict)
    return m


def set_up(d: DaemonProcess, port: str) -> None:
    """Motor 2 at OLD_POSITION; motor 0 running (a continuous Move); on the daemon's PTY,
    the set-up host's close counted (its session's end is not the test's)."""
    closed = counters(d)["peer_closed"]
    with Client(port, timeout=10) as c:
        c.move_to(2, OLD_POSITION)
        c.wait_moved(2, 20_000)
        c.move(0, True)
    if d.port is None:
        until("the set-up host's close counted", lambda: counters(d)["peer_closed"] > closed)


def answer(resp: Response) -> bytes:
    return encode_response(resp, OPTS)


def new_host_reads_its_own(port: str) -> None:
    """A new host opens the port, flushes its input, sends IsReady(1), then GetAbsPos(1):
    it reads exactly their answers, in turn."""
    with serial.Serial(port, timeout=10) as new:
        new.reset_input_buffer()
        new.write(frame(IsReady(1)))
        first = new.read(5)
        assert first == answer(Response.boolean(True)), (
            f"the new host's first answer is {first.hex(' ')}, not its IsReady(1)'s "
            f"(an old GetAbsPos(2)'s is {answer(Response.position(OLD_POSITION)).hex(' ')})"
        )
        new.write(frame(GetAbsPos(1)))
        assert new.read(5) == answer(Response.position(0))


def test_what_a_host_left_unread_behind_back_pressure_is_dropped_on_a_pty(
    tmp_path: Path,
) -> None:
    """The issue's scenario as it was seen: the host's one blocking write, from a thread."""
    d = DaemonProcess(tmp_path).start()
    try:
        port = str(d.pty)
        set_up(d, port)
        before = counters(d)
        old = serial.Serial(port, timeout=10)
        writer = Writer(old, frame(GetAbsPos(2)) * FRAMES)
        writer.start()
        until(
            "the daemon to stop reading (4096 answers owed)",
            lambda: counters(d)["backpressure"] > before["backpressure"],
        )
        old.close()  # its write done, or still waiting for room (pyserial ends it)
        until("the close counted", lambda: counters(d)["peer_closed"] > before["peer_closed"])
        assert writer.done.wait(10), "the host's write never ended"
        ended = counters(d)
        new_host_reads_its_own(port)
        assert counters(d)["frames"] == ended["frames"] + 2  # the new host's, no other
        taken = ended["frames"] - before["frames"]
        assert taken < FRAMES  # the rest waited in the kernel: the scenario
        assert ended["unread_frames_dropped"] > before["unread_frames_dropped"]
    finally:
        d.close()


def test_a_stop_move_left_unread_behind_back_pressure_is_carried_out(tmp_path: Path) -> None:
    """The host writes GetAbsPos(2) frames until the daemon stops reading (its status says
    so), then a StopMove of the running motor 0 and 100 more, and closes the port: every
    frame it wrote is accounted for, taken (answered: dropped) or read out and dropped, the
    StopMove carried out; the new host's answers are its own."""
    d = DaemonProcess(tmp_path).start()
    try:
        port = str(d.pty)
        set_up(d, port)
        before = counters(d)
        old = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            written = write_frames(old, d, before)
            after = frame(StopMove(0, False)) + frame(GetAbsPos(2)) * 100
            written += write_all(old, after)
        finally:
            os.close(old)
        until("the close counted", lambda: counters(d)["peer_closed"] > before["peer_closed"])
        ended = counters(d)
        new_host_reads_its_own(port)
        taken = ended["frames"] - before["frames"]
        unread = ended["unread_frames_dropped"] - before["unread_frames_dropped"]
        assert written % 10 == 0 and taken + unread == written // 10 and unread > 100
        assert ended["hangup_partial_bytes"] == before["hangup_partial_bytes"]
        assert ended["unread_stops_executed"] - before["unread_stops_executed"] == 1
        dropped = ended["responses_dropped_unsent"] - before["responses_dropped_unsent"]
        assert dropped == taken  # none of its answers was read, by it or anyone
        until("motor 0 stopped by the old host's StopMove", lambda: motor(d, 0)["state"] == "idle")
    finally:
        d.close()


def write_frames(fd: int, d: DaemonProcess, before: dict[str, int]) -> int:
    """GetAbsPos(2) frames, 100 at a time, each lot once the daemon has read the last one,
    until it stops reading (back pressure): the kernel then holds at most the last lot,
    with room to spare. The bytes written."""

    def held_back() -> bool:
        return counters(d)["backpressure"] > before["backpressure"]

    lot = frame(GetAbsPos(2)) * 100
    written = 0
    while not held_back():
        written += write_all(fd, lot)

        def taken_or_held(n: int = written) -> bool:
            return counters(d)["bytes_in"] - before["bytes_in"] >= n or held_back()

        until("the daemon to read the host's frames, or to stop reading", taken_or_held)
    return written


def write_all(fd: int, data: bytes) -> int:
    """All of ``data``, waiting for room in the kernel (``write_frames`` leaves some)."""
    view = memoryview(data)
    end = time.monotonic() + WAIT_S
    while view:
        assert time.monotonic() < end, "the kernel took no more of the host's bytes"
        if select.select([], [fd], [], 0.05)[1]:
            with contextlib.suppress(BlockingIOError):
                view = view[os.write(fd, view) :]
    return len(data)


@needs_socat
def test_what_a_host_left_on_its_way_behind_back_pressure_goes_with_its_serial_device(
    tmp_path: Path,
) -> None:
    pair = PtyPair(tmp_path / "ttyUSB", tmp_path / "host", tmp_path / "socat.log").start()
    d = DaemonProcess(tmp_path, port=str(pair.device))
    try:
        d.start()
        port = str(pair.host)
        set_up(d, port)
        before = counters(d)
        old = serial.Serial(port, timeout=10)
        writer = Writer(old, frame(GetAbsPos(2)) * FRAMES)
        writer.start()
        # the daemon has taken a part; the rest is on its way or held back (socat stops
        # relaying once the host's input is full of answers it does not read, at some 4,500)
        until(
            "the daemon to take the host's first 100 frames",
            lambda: counters(d)["frames"] - before["frames"] >= 100,
        )
        pair.stop()  # unplugged while the host's frames are on their way
        until("the device's loss counted", lambda: counters(d)["device_lost"] == 1)
        old.close()
        assert writer.done.wait(10), "the host's write never ended"
        taken = counters(d)["frames"] - before["frames"]
        assert taken < FRAMES  # the rest was on its way: the scenario
        pair.start()  # plugged back in, the same names
        until("the daemon to serve the device again", lambda: counters(d)["device_reopened"] == 1)
        new_host_reads_its_own(port)
        after = counters(d)
        assert after["frames"] - before["frames"] == taken + 2  # the new host's two
    finally:
        d.close()
        pair.stop()


def test_a_host_without_an_answer_is_told_what_the_link_saw(tmp_path: Path) -> None:
    """A test's host that gets no answer (here: half a frame, never answered) says what the
    daemon's link counted and who has the PTY open (tests/support/daemon_proc.py): a stolen
    answer and a frame never read look alike from the host's side."""
    d = DaemonProcess(tmp_path).start()
    try:
        with d.client(timeout=0.2) as c:
            c.send_bytes(frame(GetAbsPos(0))[:4])
            with pytest.raises(LinkError) as info:
                c.read_response()
            pts = os.readlink(d.pty)
            assert f"{d.pty} -> {pts}, open in: {os.getpid()} (" in str(info.value)
            assert "reads 1" in str(info.value)
    finally:
        d.close()
