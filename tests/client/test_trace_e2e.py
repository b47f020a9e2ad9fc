"""End to end: motorctld's trace, the reader, replay and the tap, as real processes on PTYs.

A session is recorded with ``motorctld --trace`` and replayed against a fresh daemon (clean)
and against a daemon variant whose config answers one command with another error code (the
replay names that frame); the tap sits between a host on a PTY pair and a real motorctld
standing in for the old device; tshark opens a trace when it is installed.
"""

from __future__ import annotations

import json
import os
import random
import select
import shutil
import signal
import subprocess
import sys
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.client.recording import load
from motorctl.protocol.capture.format import Direction
from motorctl.protocol.capture.reader import parse
from motorctl.protocol.codec import (
    CodecOptions,
    GetAbsPos,
    IsReady,
    MoveTo,
    WaitMoved,
    encode_command,
)
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

OPTS = CodecOptions()
CONFIG = """
[dc]
[[motors]]
name = "x"
[[motors]]
name = "y"
[[pins]]
number = 3
[[pins]]
number = 5
mode = "input"
"""
#: the same machine without pin 5: SetPin(5) answers E2 (invalid address), not E1
VARIANT = CONFIG.replace('[[pins]]\nnumber = 5\nmode = "input"\n', "")
SESSION_FRAMES = 17
#: The replays' device timing (docs/trace.md, "How the answers are judged"): these test
#: daemons run without real-time priority beside a parallel test run, and a motion of
#: theirs may slide behind its plan by half a second or more, so a WaitMoved's hold may end
#: that much later than recorded. What is tested here is the replay's reading, pairing and
#: naming of frames; how closely it judges timing: tests/client/test_judge.py, and with
#: daemons as a user starts them at the default 50 ms, bench/replay.py.
DEVICE_TIMING = ("--time-tolerance-ms", "2000")


def motorctl(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "motorctl.client.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def session(c: Client) -> None:
    """What a host does: motion synchronised by WaitMoved, waypoints, pins, errors, the DC
    motor, a frame split by a pause longer than the frame gap, a frame with a bad checksum."""
    assert c.is_ready(0)
    c.move_to(0, 400, speed=250)
    c.wait_moved(0, 5000)
    assert c.position(0) == 400
    assert c.save_waypoint(0) == 0
    c.move_to(1, -300)
    c.wait_moved(1, 5000)
    assert c.position(1) == -300
    c.set_pin(3, True)
    assert c.get_pin(3)
    with pytest.raises(DeviceError):
        c.set_pin(5, True)  # an input: E1 (the variant has no pin 5: E2)
    with pytest.raises(DeviceError):
        c.move_to(9, 1)  # E2
    c.dc_move(True, 50, False)
    c.send_bytes(encode_command(GetAbsPos(0), OPTS)[:4])  # dropped by the gap rule ...
    assert c.read_raw(5, timeout=0.1) == b""  # ... after 100 ms of silence
    c.send_frame(encode_command(IsReady(1), OPTS)[:9] + b"\x00")  # bad checksum: E1
    assert not c.read_response().ack
    c.move_to_waypoint(0, 0)
    c.wait_moved(0, 5000)
    assert c.position(0) == 400


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A session recorded by motorctld's own trace."""
    work = tmp_path_factory.mktemp("rec")
    trace = work / "session.pcapng"
    d = DaemonProcess(work, CONFIG, extra=["--trace", str(trace)]).start()
    try:
        with d.client() as c:
            session(c)
        status = d.status()
    finally:
        d.close()
    assert d.proc is not None and d.proc.returncode == 0, d.stderr()
    assert status["trace"]["file"] == str(trace) and status["trace"]["dropped_runs"] == 0
    yield trace


def test_the_reader_shows_the_session_decoded(recorded: Path) -> None:
    run = motorctl("trace", "--json", str(recorded))
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert doc["info"]["role"] == "daemon" and doc["info"]["frame_gap_ms"] == 10
    s = doc["summary"]
    assert s["frames"] == SESSION_FRAMES and s["answers"] == SESSION_FRAMES
    assert s["unanswered"] == [] and s["gap_discards"] == 1 and s["frame_errors"] == 1
    assert s["errors"] == {"E1 Invalid Command": 2, "E2 Invalid Address": 1}
    texts = [r["text"] for r in doc["rows"]]
    assert "#2 MoveTo(motor=0, dir=up, pos=400, speed=250, acc=0, dec=0)" in texts
    assert "#4 pos=400" in texts and "#5 waypoint=0" in texts
    wait = next(r for r in doc["rows"] if r["text"] == "#3 ok")
    assert wait["rtt_us"] > 300_000  # 400 steps at 1000 step/s, held until done
    table = motorctl("trace", str(recorded))
    assert "E2 Invalid Address" in table.stdout and "partial frame dropped" in table.stdout


def test_a_recorded_session_replays_clean_against_a_fresh_daemon(
    recorded: Path, tmp_path: Path
) -> None:
    d = DaemonProcess(tmp_path, CONFIG).start()
    try:
        run = motorctl("replay", str(recorded), "--port", str(d.pty), "--json", *DEVICE_TIMING)
    finally:
        d.close()
    doc = json.loads(run.stdout)
    assert run.returncode == 0, run.stdout
    assert doc["ok"] and doc["differs"] == 0 and doc["frames"] == SESSION_FRAMES
    assert doc["exact"] + doc["tolerated"] == SESSION_FRAMES
    # what depends on timing here: how long each WaitMoved was held (judged by the move)
    assert [v["command"].split("(")[0] for v in doc["verdicts"]] == ["WaitMoved"] * 3


def test_a_changed_daemon_is_caught_naming_the_frame(recorded: Path, tmp_path: Path) -> None:
    d = DaemonProcess(tmp_path, VARIANT).start()
    try:
        run = motorctl("replay", str(recorded), "--port", str(d.pty), "--fast", *DEVICE_TIMING)
    finally:
        d.close()
    assert run.returncode == 1, run.stdout + run.stderr
    diffs = [line for line in run.stdout.splitlines() if line.startswith("DIFF")]
    assert len(diffs) == 1, run.stdout
    assert "frame #11 " in diffs[0] and "SetPin(pin=5, high=true)" in diffs[0]
    assert "E1 Invalid Command" in diffs[0] and "E2 Invalid Address" in diffs[0]
    assert "1 differ" in run.stdout


def test_tshark_opens_the_trace(recorded: Path) -> None:
    if shutil.which("tshark") is None:
        pytest.skip("tshark is not installed (apt-get install tshark)")
    run = subprocess.run(
        [
            "tshark",
            "-r",
            str(recorded),
            "-T",
            "fields",
            "-e",
            "frame.packet_flags_direction",
            "-e",
            "data",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    rows = [line.split("\t") for line in run.stdout.splitlines()]
    cap = load([recorded])
    assert len(rows) == len(cap.records)
    for (flags, data), rec in zip(rows, cap.records, strict=True):
        assert int(flags, 16) & 3 == rec.direction
        assert bytes.fromhex(data) == rec.data


# --- the tap ----------------------------------------------------------------------------------


def subdir(path: Path, name: str) -> Path:
    (path / name).mkdir()
    return path / name


def pty_pair() -> tuple[int, str]:
    """A PTY in raw mode: its master (kept here) and its slave's path (for the tap)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    name = os.ttyname(slave)
    os.close(slave)
    return master, name


def start_tap(host: str, device: str, out: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "motorctl.client.cli",
            "tap",
            "--host",
            host,
            "--device",
            device,
            "--out",
            str(out),
            "--json",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert proc.stderr is not None
    assert line.startswith("motorctl tap: forwarding"), line + proc.stderr.read()
    return proc


def stop_tap(proc: subprocess.Popen[str]) -> dict[str, object]:
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    report: dict[str, object] = json.loads(out)
    return report


def read_exactly(fd: int, n: int, timeout: float = 10.0) -> bytes:
    got = b""
    while len(got) < n:
        ready, _, _ = select.select([fd], [], [], timeout)
        assert ready, f"only {got.hex(' ')} of {n} bytes within {timeout} s"
        got += os.read(fd, n - len(got))
    return got


def test_the_tap_forwards_every_byte_unchanged_and_records_both_ways(tmp_path: Path) -> None:
    """Random runs both ways between two PTY pairs: nothing altered, dropped or reordered."""
    host, host_port = pty_pair()
    device, device_port = pty_pair()
    out = tmp_path / "tap.pcapng"
    tap = start_tap(host_port, device_port, out)
    rng = random.Random(18)
    sent = {Direction.TO_DEVICE: bytearray(), Direction.TO_HOST: bytearray()}
    try:
        for _ in range(300):
            direction = rng.choice(list(Direction))
            src, dst = (host, device) if direction is Direction.TO_DEVICE else (device, host)
            data = rng.randbytes(rng.randint(1, 300))
            os.write(src, data)
            assert read_exactly(dst, len(data)) == data
            sent[direction] += data
    finally:
        report = stop_tap(tap)
        os.close(host)
        os.close(device)
    cap = parse(out.read_bytes())
    assert cap.info is not None and cap.info.role == "tap" and cap.problems == []
    for direction in Direction:
        recorded = b"".join(r.data for r in cap.records if r.direction is direction)
        assert recorded == bytes(sent[direction])
    assert report["bytes_to_device"] == len(sent[Direction.TO_DEVICE])
    assert report["bytes_to_host"] == len(sent[Direction.TO_HOST])
    times = [r.ts_ns for r in cap.records]
    assert times == sorted(times)


def test_the_tap_between_a_host_and_motorctld_records_a_replayable_session(tmp_path: Path) -> None:
    """A host on a PTY pair, the tap, a real motorctld as the old device (with its own trace
    for comparison); the recording then replays clean against a fresh daemon."""
    old = DaemonProcess(
        subdir(tmp_path, "old"), CONFIG, extra=["--trace", str(tmp_path / "device.pcapng")]
    ).start()
    host, host_port = pty_pair()
    out = tmp_path / "tap.pcapng"
    tap = start_tap(host_port, str(old.pty), out)
    frames = [
        encode_command(c, OPTS)
        for c in (
            IsReady(0),
            MoveTo(0, True, 300, 250, 0, 0),
            WaitMoved(0, 5000),
            GetAbsPos(0),
            MoveTo(7, True, 1, 0, 0, 0),
        )
    ]
    answers = []
    try:
        for f in frames:
            os.write(host, f[:3])
            os.write(host, f[3:])
            answers.append(read_exactly(host, 5))
        os.write(host, frames[0][:5])  # half a frame, then silence: the gap rule drops it
        ready, _, _ = select.select([host], [], [], 0.1)
        assert not ready
    finally:
        stop_tap(tap)
        os.close(host)
        old.close()
    assert answers[0] == bytes.fromhex("01 01 00 00 6b")
    assert answers[3][:4] == bytes.fromhex("01 00 01 2c")  # at 300
    assert answers[4][:2] == b"\x00\xe2"
    tapped = parse(out.read_bytes())
    own = load([tmp_path / "device.pcapng"])
    for direction in Direction:  # the tap saw what the device saw, byte for byte
        assert b"".join(r.data for r in tapped.records if r.direction is direction) == b"".join(
            r.data for r in own.records if r.direction is direction
        )
    fresh = DaemonProcess(subdir(tmp_path, "fresh"), CONFIG).start()
    try:
        run = motorctl("replay", str(out), "--port", str(fresh.pty), *DEVICE_TIMING)
    finally:
        fresh.close()
    assert run.returncode == 0, run.stdout + run.stderr
    assert "4 answers byte-exact, 1 within tolerance, 0 differ" in run.stdout  # the WaitMoved
