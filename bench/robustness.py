"""The robustness harness: motorctld as a subprocess on a PTY, driven by an independent host.

Over 500 lines on purpose: one harness, run as ``python -m bench.robustness``, whose
host side is deliberately written from PROTOCOL.md alone (below), so it shares nothing with
the package and keeps its own helpers beside its parts.

    python -m bench.robustness                 # everything: frames, kill -9, soak (~20 min)
    python -m bench.robustness --quick         # a short run of each part (~2 min)
    python -m bench.robustness --parts frames --frames 1000000 --json out.json

The host side here is written from PROTOCOL.md alone: its own CRC-8/SMBUS, its own frame
layouts and its own response checks; nothing from motorctl.protocol is used to build or
check bytes. (It reads the daemon's counters through the status socket, the daemon's
documented status interface, only to report them and to wait for a gap discard.)

Parts (each reports its figures and every invariant violation; exit status 1 if any):
- frames: random bytes, valid frames with random fields, frames with one flipped bit,
  truncated frames, bursts of up to 10,000 frames in one write, frames byte by byte with
  random delays below the gap, while motors 1 and 2 move. Invariants: exactly one response
  per complete frame, each well-formed with a valid CRC; exact expected answers for the
  deterministic queries (so order and alignment are checked); nothing executed from a bad
  frame (motor 0's position, state and waypoint count, all pins unchanged); the daemon's
  counters agree with what was sent; alive and answering at the end.
- kill: kill -9 at random moments (within ms of a motion start, right after a SaveWayPoint
  or SaveHome ACK, mid-move, at rest), restart on the same state directory, then check that
  no motor reports a wrong position as valid and that home and every acknowledged waypoint
  are there (and hold the right values).
- faults: the state directory turns read-only (a read-only bind mount onto itself; needs
  root, else skipped and said so): SaveHome/SaveWayPoint must answer E4 and change nothing, the
  daemon keeps serving, and after a kill -9 every acknowledged save is there. (Line and
  driver faults are injected in-process: tests/daemon/test_dispatcher_faults.py.)
- soak: mixed traffic as fast as the host can send while 3 motors move, for --soak-s
  seconds: RSS and open file descriptors of the daemon sampled; error counters must only
  grow by what the traffic provokes.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from motorctl.daemon.status.reader import read_status

ROOT = Path(__file__).resolve().parent.parent
# The harness's daemon uses a 100 ms gap: this host is a Python process on a shared machine
# and may itself be descheduled for tens of ms between two writes. A pause that long in the
# middle of a frame is a real gap on the line, which the daemon must (and does) discard; a
# wider gap keeps the host's own stalls from being gaps, so that every discard the harness
# sees is one it made on purpose.
GAP_S = 0.100
READY_TIMEOUT_S = 30.0
RESPONSE_TIMEOUT_S = 30.0

# A world in which motion is quick, so that 100 kill cycles take minutes, not hours.
CONFIG = """
[link]
frame_gap_ms = 100.0
[units]
move_speed_factor = 100.0
run_speed_factor = 100.0
[step_thread]
priority = 0
lock_memory = false
[dc]
[mock]
wires = [[0, 4], [1, 5], [2, 6], [3, 7]]
"""
for _name in ("x", "y", "z"):
    CONFIG += f"""
[[motors]]
name = "{_name}"
default_speed = 20000.0
default_accel = 200000.0
default_decel = 200000.0
  [motors.homing]
  speed = 20000.0
"""
for _n in range(8):
    CONFIG += f'\n[[pins]]\nnumber = {_n}\nmode = "{"output" if _n < 4 else "input"}"\n'


# -- the protocol, from PROTOCOL.md, independently of motorctl.protocol ------------------
def crc8_bitwise(data: bytes) -> int:
    """CRC-8/SMBUS bit by bit: poly 0x07, init 0, not reflected, xorout 0."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


_TABLE = [crc8_bitwise(bytes([i])) for i in range(256)]


def crc8(data: bytes) -> int:
    """The same CRC, a byte at a time from a table made by the bitwise one."""
    crc = 0
    for byte in data:
        crc = _TABLE[crc ^ byte]
    return crc


assert crc8_bitwise(b"123456789") == crc8(b"123456789") == 0xF4, "the harness's CRC is wrong"

# Parameter field sizes after B0, per PROTOCOL.md §3.
FIELDS: dict[int, tuple[int, ...]] = {
    0x00: (1, 1, 1, 1, 1),  # InitMove MOTOR DIR SPEED ACC DEC
    0x01: (1, 1, 3, 1, 1, 1),  # MoveTo MOTOR DIR POS SPEED ACC DEC
    0x02: (1, 2),  # WaitMoved MOTOR TIMEOUT
    0x03: (1,),  # IsReady
    0x04: (1, 1, 1, 1, 1),  # Move
    0x05: (1, 1),  # StopMove MOTOR IS_HARDSTOP
    0x06: (1,),  # GetAbsPos
    0x07: (1, 1),  # SetPin PIN IS_HIGH
    0x08: (1,),  # GetPin
    0x09: (1, 1),  # ConfigPin PIN IS_OUTPUT
    0x0A: (1,),  # SaveHome
    0x0B: (1,),  # GoHome
    0x0C: (1,),  # SaveWayPoint
    0x0D: (1, 1, 1, 1, 1),  # MoveToWayPoint MOTOR WP SPEED ACC DEC
    0x0E: (1, 2, 1),  # DcMove DIR TIME GO_HiZ
}
INIT_MOVE, MOVE_TO, WAIT, IS_READY, MOVE, STOP, GET_POS = range(7)
SET_PIN, GET_PIN, CONFIG_PIN, SAVE_HOME, GO_HOME, SAVE_WP, MOVE_TO_WP, DC_MOVE = range(7, 15)
E0, E1, E2, E3, E4, E5, E6 = range(0xE0, 0xE7)


def cmd(code: int, *values: int) -> bytes:
    body = bytearray([code])
    for size, value in zip(FIELDS[code], values, strict=True):
        body += (value & ((1 << (8 * size)) - 1)).to_bytes(size, "big")
    body += bytes(9 - len(body))
    return bytes(body) + bytes([crc8(bytes(body))])


def ok(payload: bytes = b"\0\0\0") -> bytes:
    return b"\x01" + payload + bytes([crc8(payload)])


def err(code: int) -> bytes:
    payload = bytes([code, 0, 0])
    return b"\x00" + payload + bytes([crc8(payload)])


def pos_bytes(p: int) -> bytes:
    return (p & 0xFFFFFF).to_bytes(3, "big")


def pos_of(resp: bytes) -> int:
    v = int.from_bytes(resp[1:4], "big")
    return v - (1 << 24) if v & 0x800000 else v


def malformed(resp: bytes) -> str | None:
    """Why a 5-byte response is not well-formed per PROTOCOL.md §1/§5, or None."""
    if len(resp) != 5:
        return f"length {len(resp)}"
    if resp[4] != crc8(resp[1:4]):
        return f"bad CRC in {resp.hex()}"
    if resp[0] not in (0, 1):
        return f"R0 not 0/1 in {resp.hex()}"
    if resp[0] == 0 and (resp[1] not in range(0xE0, 0xE7) or resp[2] or resp[3]):
        return f"bad error response {resp.hex()}"
    return None


def frame_valid(frame: bytes) -> bool:
    """Would a correct daemon execute this 10-byte frame (CRC, code, zero padding)?"""
    if frame[9] != crc8(frame[:9]) or frame[0] not in FIELDS:
        return False
    used = 1 + sum(FIELDS[frame[0]])
    return not any(frame[used:9])


# -- the daemon and the port -----------------------------------------------------------
class Daemon:
    def __init__(self, workdir: Path, state_dir: Path) -> None:
        self.workdir = workdir
        self.pty = workdir / "motorctl.pty"
        self.state_dir = state_dir
        self.config = workdir / "robustness.toml"
        self.config.write_text(CONFIG)
        self.stderr = workdir / "motorctld.stderr"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> Daemon:
        cmdline = [
            sys.executable,
            "-m",
            "motorctl.daemon.start.launch",
            "--pty",
            str(self.pty),
            "--state-dir",
            str(self.state_dir),
            "--config",
            str(self.config),
            "--log-level",
            "warning",
        ]
        with open(self.stderr, "ab") as err_file:
            self.proc = subprocess.Popen(cmdline, stdout=subprocess.PIPE, stderr=err_file, cwd=ROOT)
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        line = b""
        end = time.monotonic() + READY_TIMEOUT_S
        while not line.endswith(b"\n"):
            left = end - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                self.kill()
                raise RuntimeError(f"motorctld not ready in {READY_TIMEOUT_S} s")
            chunk = os.read(fd, 256)
            if not chunk:
                raise RuntimeError(f"motorctld exited: {self.stderr.read_text()[-2000:]}")
            line += chunk
        return self

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def status(self) -> dict[str, Any]:
        return read_status(self.state_dir / "status.sock")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)
        self._close_pipe()

    def terminate(self) -> int:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM)
        rc = self.proc.wait(30)
        self._close_pipe()
        return rc

    def _close_pipe(self) -> None:
        if self.proc is not None and self.proc.stdout is not None:
            self.proc.stdout.close()

    def rss_kib(self) -> int:
        for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        return -1

    def fds(self) -> int:
        return len(os.listdir(f"/proc/{self.pid}/fd"))


class Port:
    """The host's end of the PTY: writes block (with a deadline), a thread reads all."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self._buf = bytearray()
        self._cond = threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop:
            if not select.select([self.fd], [], [], 0.1)[0]:
                continue
            try:
                data = os.read(self.fd, 65536)
            except BlockingIOError:
                continue
            except OSError:
                return
            with self._cond:
                self._buf += data
                self._cond.notify_all()

    # A UART's bytes do not stall: while it writes, the host thread asks for SCHED_FIFO so
    # that the machine's other processes do not cut a frame in two (best effort; root).
    realtime_writes = True

    def write(self, data: bytes, timeout: float = RESPONSE_TIMEOUT_S) -> None:
        if Port.realtime_writes:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
            except OSError:
                Port.realtime_writes = False
        try:
            self._write(data, timeout)
        finally:
            if Port.realtime_writes:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    # The host's own honesty about gaps: ``phase`` is the offset in the current frame after
    # the last byte written; ``stall`` the longest the line may have been silent in the
    # middle of a frame (from the start of one write to the end of the next) since
    # :meth:`clear_stall`. Above GAP_S the host may itself have made a real gap.
    phase = 0
    stall = 0.0
    _last_start = 0.0
    _full = False

    def clear_stall(self, phase: int | None = None) -> None:
        self.stall = 0.0
        if phase is not None:
            self.phase = phase

    def _write(self, data: bytes, timeout: float) -> None:
        view = memoryview(data)
        end = time.monotonic() + timeout
        while view:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("the daemon stopped taking the host's bytes")
            if select.select([], [self.fd], [], min(left, 0.1))[1]:
                start = time.monotonic()
                chunk = view[:65536]
                try:
                    n = os.write(self.fd, chunk)
                except BlockingIOError:
                    self._full = True
                    continue
                done = time.monotonic()
                # After a write the kernel only partly took, the host waits for room: the
                # daemon has bytes to read, the line is not silent for it, no stall.
                if self.phase and not self._full:
                    self.stall = max(self.stall, done - self._last_start)
                self._full = n < len(chunk)
                self._last_start = start
                self.phase = (self.phase + n) % 10
                view = view[n:]

    def take(self, n: int, timeout: float = RESPONSE_TIMEOUT_S) -> bytes:
        """Exactly n bytes, or fewer if the deadline passes."""
        end = time.monotonic() + timeout
        with self._cond:
            while len(self._buf) < n:
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            data = bytes(self._buf[:n])
            del self._buf[:n]
            return data

    def extra(self, within: float) -> bytes:
        """Whatever arrives within ``within`` seconds (should be nothing)."""
        time.sleep(within)
        with self._cond:
            data = bytes(self._buf)
            self._buf.clear()
            return data

    def close(self) -> None:
        self._stop = True
        self._thread.join(2)
        os.close(self.fd)


class Report:
    def __init__(self) -> None:
        self.violations: list[str] = []
        self.figures: dict[str, Any] = {}
        self.host_stalls = 0  # segments skipped because the host itself made a gap
        self.skipped_frames = 0  # the frames in them (sent, answered, not checked)
        self.resync = False  # set after a skipped segment: re-read the daemon's discards

    def violation(self, what: str) -> None:
        if len(self.violations) < 1000:
            self.violations.append(what)
        print(f"  VIOLATION: {what}", flush=True)


def exchange(
    port: Port,
    frames: Sequence[bytes],
    report: Report,
    expected: Sequence[bytes | None] | None = None,
    what: str = "",
) -> list[bytes]:
    """Send frames in one write; read one response each; check form and expected bytes."""
    port.clear_stall()
    port.write(b"".join(frames))
    if port.stall > GAP_S:
        recover_from_host_stall(port, report, what)
        report.skipped_frames += len(frames)
        return []
    data = port.take(5 * len(frames))
    if len(data) != 5 * len(frames):
        report.violation(f"{what}: {len(data) // 5} responses to {len(frames)} frames")
    rs = [data[i : i + 5] for i in range(0, len(data) - 4, 5)]
    for i, r in enumerate(rs):
        bad = malformed(r)
        if bad:
            report.violation(f"{what}: response {i}: {bad}")
        elif expected is not None and (want := expected[i]) is not None and r != want:
            report.violation(
                f"{what}: response {i} to {frames[i].hex()} is {r.hex()}, expected {want.hex()}"
            )
    return rs


def recover_from_host_stall(port: Port, report: Report, what: str) -> None:
    """The host was descheduled mid-frame for longer than the gap: a real gap, which the
    daemon may rightly have used to discard a partial frame. Nothing about this segment
    can be asserted; keep silent, drop its answers, and go on from the daemon's count."""
    report.host_stalls += 1
    print(
        f"  host stalled {port.stall * 1000:.0f} ms mid-frame in {what}: segment skipped",
        flush=True,
    )
    time.sleep(3 * GAP_S)
    port.extra(0.5)
    port.clear_stall(0)
    report.resync = True


def ask(port: Port, frame: bytes, report: Report, what: str) -> bytes:
    rs = exchange(port, [frame], report, what=what)
    return rs[0] if rs else b""


def wait_idle(port: Port, motor: int, report: Report, timeout_s: float = 20.0) -> bytes:
    return ask(port, cmd(WAIT, motor, int(timeout_s * 1000)), report, f"WaitMoved({motor})")


# -- part 1: a million frames ---------------------------------------------------------
class Baseline:
    """What a bad frame must not change: motor 0 (at rest), all pins, motor 0's waypoints."""

    def __init__(self, port: Port, report: Report) -> None:
        self.port, self.report = port, report
        self.waypoints = 0
        self.take()

    def take(self) -> None:
        p, r = self.port, self.report
        for m in range(3):
            ask(p, cmd(STOP, m, 1), r, "StopMove")  # ends motion, clears faults
        for m in range(3):
            ask(p, cmd(STOP, m, 1), r, "StopMove")  # a second time: the fault is clear now
        # The step executor confirms a stop a moment later: wait for motor 0 to be at rest.
        if (w := wait_idle(p, 0, r, 5.0)) != ok():
            r.violation(f"motor 0 not at rest 5 s after a hard StopMove: {w.hex()}")
        self.pos0 = pos_of(ask(p, cmd(GET_POS, 0), r, "GetAbsPos(0)"))
        self.pins = {n: ask(p, cmd(GET_PIN, n), r, "GetPin") for n in range(8)}

    def queries(self, rng: random.Random, n: int) -> tuple[list[bytes], list[bytes | None]]:
        """n deterministic query frames and their exact answers (alignment and invariants)."""
        frames: list[bytes] = []
        answers: list[bytes | None] = []
        for _ in range(n):
            k = rng.randrange(7)
            if k == 0:
                frames.append(cmd(GET_POS, 0))
                answers.append(ok(pos_bytes(self.pos0)))
            elif k == 1:
                frames.append(cmd(IS_READY, 0))
                answers.append(ok(b"\x01\0\0"))
            elif k == 2:
                pin = rng.randrange(8)
                frames.append(cmd(GET_PIN, pin))
                answers.append(self.pins[pin])
            elif k == 3:
                frames.append(cmd(GET_POS, rng.randrange(3, 256)))
                answers.append(err(E2))
            elif k == 4:
                frames.append(cmd(MOVE_TO_WP, 0, self.waypoints, 0, 0, 0))
                answers.append(err(E6) if self.waypoints < 256 else None)
            elif k == 5:
                frames.append(cmd(GET_POS, rng.choice((1, 2))))
                answers.append(None)  # moving: any well-formed answer
            else:
                code = bytes([rng.randrange(0x0F, 0x100)]) + bytes(8)
                frames.append(code + bytes([crc8(code)]))
                answers.append(err(E1))  # an unknown command code
        return frames, answers


def bad_frame(rng: random.Random, kind: str) -> bytes:
    """A frame that a correct daemon must answer E1 and not execute, aimed at the quiet
    motor 0, the pins, the waypoint table and the DC motor."""
    victims = [
        cmd(MOVE_TO, 0, 1, rng.randrange(-5000, 5000), 10, 10, 10),
        cmd(MOVE, 0, rng.randrange(2), 1, 0, 0),
        cmd(INIT_MOVE, 0, 0, 1, 0, 0),
        cmd(SET_PIN, rng.randrange(4), rng.randrange(2)),
        cmd(CONFIG_PIN, rng.randrange(8), rng.randrange(2)),
        cmd(SAVE_WP, 0),
        cmd(SAVE_HOME, 0),
        cmd(GO_HOME, 0),
        cmd(MOVE_TO_WP, 0, 0, 0, 0, 0),
        cmd(DC_MOVE, 1, 500, 0),
        cmd(STOP, 1, 1),
    ]
    frame = bytearray(rng.choice(victims))
    if kind == "flip":
        bit = rng.randrange(80)
        frame[bit // 8] ^= 1 << (bit % 8)
    else:  # padding: a valid CRC over non-zero padding
        used = 1 + sum(FIELDS[frame[0]])
        if used < 9:
            frame[rng.randrange(used, 9)] = rng.randrange(1, 256)
            frame[9] = crc8(bytes(frame[:9]))
        else:
            frame[9] ^= 0xFF
    assert not frame_valid(bytes(frame))
    return bytes(frame)


def random_valid(rng: random.Random) -> bytes:
    code = rng.randrange(15)
    values = [rng.randrange(1 << (8 * s)) for s in FIELDS[code]]
    if code not in (SET_PIN, GET_PIN, CONFIG_PIN, DC_MOVE) and rng.random() < 0.8:
        values[0] = rng.randrange(4)  # mostly real motors (3 = E2)
    if code == WAIT:
        values[1] = rng.randrange(30)  # keep the link moving
    if code == DC_MOVE:
        values[1] = rng.randrange(200)
    return cmd(code, *values)


class Movers:
    """Keeps motors 1 and 2 moving back and forth around 0."""

    def __init__(self, port: Port, report: Report) -> None:
        self.port, self.report = port, report
        self.last = 0.0
        self.up = True
        self.faults = 0

    def kick(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self.last < 0.5:
            return
        self.last = now
        for m in (1, 2):
            pos = pos_of(ask(self.port, cmd(GET_POS, m), self.report, "GetAbsPos"))
            up = pos < 0 if abs(pos) > 1500 else self.up
            move = cmd(MOVE, m, int(up), 3, 0, 0)  # 300 step/s
            r = ask(self.port, move, self.report, "Move")
            if r == err(E4):  # a random frame ran it into an end stop: a latched fault
                self.faults += 1
                for _ in range(2):
                    ask(self.port, cmd(STOP, m, 1), self.report, "StopMove")
                r = ask(self.port, move, self.report, "Move")
            if r != ok():
                self.report.violation(f"Move for mover {m} answered {r.hex()}")
        self.up = not self.up


def part_frames(workdir: Path, total: int, seed: int, report: Report) -> None:
    rng = random.Random(seed)
    violations_before = len(report.violations)
    d = Daemon(workdir, workdir / "state").start()
    port = Port(d.pty)
    sent = {
        "burst": 0,
        "bytewise": 0,
        "random_bytes": 0,
        "flipped": 0,
        "padding": 0,
        "truncated": 0,
        "valid_random": 0,
        "queries": 0,
    }
    frames_total = 0
    discards = 0
    base = Baseline(port, report)
    movers = Movers(port, report)
    movers.kick(force=True)
    t0 = time.monotonic()
    last_print = t0
    try:
        while frames_total < total and len(report.violations) == violations_before:
            movers.kick()
            kind = rng.choices(
                [
                    "burst",
                    "bytewise",
                    "random_bytes",
                    "flipped",
                    "padding",
                    "truncated",
                    "valid_random",
                ],
                weights=[30, 2, 10, 10, 5, 5, 8],
            )[0]
            if kind == "burst":
                n = rng.randrange(1, 10_001)
                frames, answers = base.queries(rng, n)
                exchange(port, frames, report, answers, "burst")
                sent["burst"] += n
                frames_total += n
            elif kind == "bytewise":
                frames, answers = base.queries(rng, rng.randrange(1, 6))
                port.clear_stall()
                for byte in b"".join(frames):
                    port.write(bytes([byte]))
                    time.sleep(rng.uniform(0, 0.2 * GAP_S))
                if port.stall > GAP_S:
                    recover_from_host_stall(port, report, "byte by byte")
                    report.skipped_frames += len(frames)
                    frames, answers = [], []
                data = port.take(5 * len(frames))
                each = [data[i : i + 5] for i in range(0, len(data), 5)]
                if len(each) != len(answers) or any(
                    malformed(g) or (a is not None and g != a)
                    for g, a in zip(each, answers, strict=True)
                ):
                    report.violation(
                        f"byte by byte: got {data.hex()}, expected "
                        f"{[a.hex() if a else 'any' for a in answers]}"
                    )
                sent["bytewise"] += len(frames)
                frames_total += len(frames)
            elif kind in ("random_bytes", "truncated"):
                if kind == "random_bytes":
                    junk = bytearray(rng.randbytes(rng.randrange(1, 400)))
                    for i in range(0, len(junk) - 9, 10):  # a valid frame by chance: spoil it
                        if frame_valid(bytes(junk[i : i + 10])):
                            junk[i + 9] ^= 0xFF
                else:
                    junk = bytearray(
                        rng.choice(
                            [cmd(MOVE_TO, 0, 1, 3000, 0, 0, 0), cmd(SET_PIN, 0, 1), cmd(SAVE_WP, 0)]
                        )[: rng.randrange(1, 10)]
                    )
                complete = len(junk) // 10
                port.write(bytes(junk))
                got = port.take(5 * complete)
                for i in range(0, len(got), 5):
                    if got[i : i + 5] != err(E1):
                        report.violation(f"{kind}: answered {got[i : i + 5].hex()}, not E1")
                if len(got) != 5 * complete:
                    report.violation(f"{kind}: {len(got) // 5} responses to {complete} frames")
                if len(junk) % 10:
                    discards += 1
                    wait_for_discard(d, discards, report)
                port.clear_stall(0)
                sent[kind] += complete if kind == "random_bytes" else 1
                frames_total += max(complete, 1)
            elif kind in ("flipped", "padding"):
                n = rng.randrange(1, 2000)
                frames = [bad_frame(rng, "flip" if kind == "flipped" else "pad") for _ in range(n)]
                exchange(port, frames, report, [err(E1)] * n, kind)
                sent[kind] += n
                frames_total += n
            else:  # valid frames with random fields
                n = rng.randrange(1, 500)
                frames = [random_valid(rng) for _ in range(n)]
                rs = exchange(port, frames, report, None, "valid random")
                for f, r in zip(frames, rs, strict=False):
                    if f[0] == SAVE_WP and f[1] == 0 and r[0] == 1:
                        if r[1] != base.waypoints:
                            report.violation(
                                f"SaveWayPoint(0) numbered {r[1]}, expected {base.waypoints}"
                            )
                        base.waypoints = r[1] + 1
                base.take()  # the random frames may have moved motor 0 or set pins
                movers.kick(force=True)
                sent["valid_random"] += n
                frames_total += n
            if report.resync:  # a skipped segment: the daemon's discards are the truth now
                report.resync = False
                discards = d.status()["link"]["counters"]["gap_discards"]
            # after every bad segment: the deterministic queries see nothing changed
            frames, answers = base.queries(rng, 20)
            exchange(port, frames, report, answers, f"check after {kind}")
            sent["queries"] += 20
            frames_total += 20
            if time.monotonic() - last_print > 10:
                last_print = time.monotonic()
                rate = frames_total / (last_print - t0)
                print(f"  {frames_total} frames, {rate:.0f} frames/s", flush=True)
        elapsed = time.monotonic() - t0
        t = time.monotonic()
        alive = ask(port, cmd(IS_READY, 0), report, "final IsReady")
        answer_s = time.monotonic() - t
        if alive != ok(b"\x01\0\0") or answer_s > 1.0:
            report.violation(f"final IsReady: {alive.hex()} after {answer_s:.3f} s")
        status = d.status()
        counters = status["link"]["counters"]
        if counters["gap_discards"] != discards:
            report.violation(
                f"daemon counted {counters['gap_discards']} gap discards, the host made {discards}"
            )
        extra = port.extra(0.2)
        if extra:
            report.violation(f"{len(extra)} bytes nobody asked for: {extra[:40].hex()}")
        report.figures["frames"] = {
            "frames": frames_total,
            "seconds": round(elapsed, 1),
            "frames_per_s": round(frames_total / elapsed),
            "by_kind": sent,
            "gap_discards_made": discards,
            "final_answer_ms": round(answer_s * 1000, 2),
            "mover_faults_cleared": movers.faults,
            "daemon_counters": counters,
            "processing": status["link"]["processing"],
            "steps": status["steps"],
        }
        print(
            f"  frames: {frames_total} in {elapsed:.1f} s = {frames_total / elapsed:.0f} frames/s",
            flush=True,
        )
    finally:
        port.close()
        if d.alive():
            rc = d.terminate()
            if rc != 0:
                report.violation(f"daemon exit status {rc} on SIGTERM")


def wait_for_discard(d: Daemon, expected: int, report: Report) -> None:
    """The host stays silent until the daemon has watched the gap (at least GAP_S)."""
    time.sleep(GAP_S)
    end = time.monotonic() + 5.0
    while d.status()["link"]["counters"]["gap_discards"] < expected:
        if time.monotonic() > end:
            report.violation("a partial frame was not discarded after 5 s of silence")
            return
        time.sleep(0.005)


# -- part 2: kill -9 -------------------------------------------------------------------
class MotorModel:
    """What the host knows about a motor across daemon restarts."""

    def __init__(self) -> None:
        self.home = 0
        self.home_pending: int | None = None  # a SaveHome sent, its ACK not seen
        self.waypoints: list[int] = []
        self.wp_pending: int | None = None
        self.position: set[int] = {0}  # the positions it may validly report


def part_kill(workdir: Path, cycles: int, seed: int, report: Report) -> None:
    rng = random.Random(seed)
    state = workdir / "state"
    models = [MotorModel() for _ in range(3)]
    outcomes: dict[str, int] = {}
    lost_seen = 0
    t0 = time.monotonic()
    for cycle in range(cycles):
        d = Daemon(workdir, state).start()
        _current_daemon[:] = [d]
        port = Port(d.pty)
        try:
            lost_seen += check_after_restart(d, port, models, report, cycle)
            moment = rng.choice(
                [
                    "motion_start",
                    "after_waypoint_ack",
                    "after_home_ack",
                    "mid_move",
                    "at_rest",
                    "during_burst",
                ]
            )
            outcomes[moment] = outcomes.get(moment, 0) + 1
            provoke(port, models, rng, moment, report)
        finally:
            d.kill()
            port.close()
    report.figures["kill"] = {
        "cycles": cycle + 1,
        "moments": outcomes,
        "losses": sum("kill" in v for v in report.violations),
        "restarts_with_lost_positions": lost_seen,
        "seconds": round(time.monotonic() - t0, 1),
        "waypoints_acknowledged": [len(m.waypoints) for m in models],
    }
    print(f"  kill -9: {cycle + 1} cycles, {lost_seen} motors restarted lost (homed again)")


def check_after_restart(
    d: Daemon, port: Port, models: list[MotorModel], report: Report, cycle: int
) -> int:
    lost = 0
    status = d.status()
    for i, m in enumerate(models):
        st = status["motors"][i]
        what = f"cycle {cycle} motor {i}"
        if not st["position_lost"] and st["position"] not in m.position:
            report.violation(
                f"kill {what}: reports position {st['position']} as valid; it "
                f"can only be one of {sorted(m.position)}"
            )
        # Every acknowledged waypoint is there: E6 would say it is not (E6 precedes E4).
        for n in range(len(m.waypoints)):
            r = ask(port, cmd(MOVE_TO_WP, i, n, 0, 0, 0), report, what)
            if r == err(E6):
                report.violation(f"kill {what}: acknowledged waypoint {n} is gone")
                del m.waypoints[n:]  # go on from what the daemon has
                break
            elif r == ok():
                wait_idle(port, i, report)
                got = pos_of(ask(port, cmd(GET_POS, i), report, what))
                if got != m.waypoints[n]:
                    report.violation(
                        f"{what}: waypoint {n} took it to {got}, saved at {m.waypoints[n]}"
                    )
            elif r != err(E4):
                report.violation(f"{what}: MoveToWayPoint({n}) answered {r.hex()}")
        if m.wp_pending is not None:  # saved or not: both are right, the host never knew
            r = ask(port, cmd(MOVE_TO_WP, i, len(m.waypoints), 0, 0, 0), report, what)
            if r != err(E6):
                m.waypoints.append(m.wp_pending)
                if r == ok():
                    wait_idle(port, i, report)
            m.wp_pending = None
        if st["position_lost"]:
            lost += 1
            if ask(port, cmd(SAVE_WP, i), report, what) != err(E4):
                report.violation(f"{what}: SaveWayPoint accepted on a lost position")
            if ask(port, cmd(INIT_MOVE, i, 0, 200, 0, 0), report, what) != ok():
                report.violation(f"{what}: InitMove refused")
            if wait_idle(port, i, report) != ok():
                report.violation(f"{what}: homing failed")
        # Home is there and holds its value (a pending SaveHome may or may not have landed);
        # a home of 0 right after homing is just off the end stop (GoHome must not hit it).
        if ask(port, cmd(GO_HOME, i), report, what) != ok():
            report.violation(f"{what}: GoHome refused")
            continue
        wait_idle(port, i, report)
        got = pos_of(ask(port, cmd(GET_POS, i), report, what))
        homes = {m.home} | ({m.home_pending} if m.home_pending is not None else set())
        if got not in homes:
            report.violation(f"kill {what}: GoHome went to {got}, home is {sorted(homes)}")
            ask(port, cmd(STOP, i, 1), report, what)  # it may have run into the end stop
            exchange(port, [cmd(MOVE_TO, i, 1, 1000, 0, 0, 0)], report, [ok()], what)
            wait_idle(port, i, report)
            exchange(port, [cmd(SAVE_HOME, i)], report, [ok()], what)
            got = 1000
        m.home = got
        m.home_pending = None
        m.position = {got}
    return lost


def state_of(port: Port, motor: int) -> str:
    """The daemon's own view of a motor, for a violation's message."""
    del port
    try:
        return str(_current_daemon[0].status()["motors"][motor]) if _current_daemon else ""
    except OSError as exc:
        return f"(no status: {exc})"


_current_daemon: list[Daemon] = []


def provoke(
    port: Port, models: list[MotorModel], rng: random.Random, moment: str, report: Report
) -> None:
    """Do something, then return at the moment the daemon is to be killed."""
    i = rng.randrange(3)
    m = models[i]
    here = next(iter(m.position))
    target = here
    while abs(target - here) < 50:
        target = rng.randrange(200, 3000)
    move = cmd(MOVE_TO, i, 1, target, rng.randrange(1, 256), 0, 0)
    if moment in ("after_waypoint_ack", "after_home_ack"):
        code = SAVE_WP if moment == "after_waypoint_ack" else SAVE_HOME
        if code == SAVE_WP and len(m.waypoints) >= 250:
            code = SAVE_HOME
        if code == SAVE_WP:
            m.wp_pending = here
        else:
            m.home_pending = here
        r = ask(port, cmd(code, i), report, moment)
        if r[:1] == b"\x01":
            if code == SAVE_WP:
                if r[1] != len(m.waypoints):
                    report.violation(f"SaveWayPoint numbered {r[1]}, expected {len(m.waypoints)}")
                m.waypoints.append(here)
                m.wp_pending = None
            else:
                m.home = here
                m.home_pending = None
        else:
            report.violation(f"{moment}: motor {i} answered {r.hex()} at rest: {state_of(port, i)}")
        return  # killed right after the ACK
    m.position = {here, target}  # sent, not acknowledged: either may be right
    if moment == "during_burst":
        port.write(move + b"".join(cmd(GET_POS, i) for _ in range(500)))
        time.sleep(rng.uniform(0, 0.01))
        return
    r = ask(port, move, report, moment)
    if r != ok():
        report.violation(f"{moment}: MoveTo answered {r.hex()}")
    # Acknowledged: the motor is moving. After a kill it is either lost, or at rest at the
    # target (the move was over and written); the start position reported as valid is the
    # stale-position hole of PROTOCOL.md §4.
    m.position = {target}
    if moment == "motion_start":
        time.sleep(rng.uniform(0, 0.005))
    elif moment == "mid_move":
        time.sleep(rng.uniform(0.005, 0.2))
    else:  # at rest: the move is over and its end has had time to be written
        wait_idle(port, i, report)
        m.position = {target}
        time.sleep(rng.uniform(0, 0.05))


# -- part 3: soak ----------------------------------------------------------------------
def part_soak(workdir: Path, seconds: float, seed: int, report: Report) -> None:
    rng = random.Random(seed)
    violations_before = len(report.violations)
    stalls_before = report.host_stalls
    d = Daemon(workdir, workdir / "soak-state").start()
    port = Port(d.pty)
    samples: list[dict[str, float]] = []
    frames_total = 0
    provoked = {"sent_E1": 0}
    t0 = time.monotonic()
    try:
        base = Baseline(port, report)
        for mot in range(3):  # all three move, back and forth, all the time
            exchange(port, [cmd(MOVE, mot, mot % 2, 20, 0, 0)], report, [ok()], "Move")
        first = d.status()["link"]["counters"]
        next_sample = t0
        flip = t0
        frames: list[bytes] = []
        answers: list[bytes | None] = []
        up = True
        while time.monotonic() - t0 < seconds and len(report.violations) == violations_before:
            now = time.monotonic()
            if now >= flip:  # reverse every second, and always back towards 0 when far out
                flip = now + 1.0
                up = not up
                moves = []
                for mot in range(3):
                    pos = pos_of(ask(port, cmd(GET_POS, mot), report, "GetAbsPos"))
                    way = (int(up) ^ (mot % 2)) if abs(pos) < 2000 else int(pos < 0)
                    moves.append(cmd(MOVE, mot, way, 20, 0, 0))
                exchange(port, moves, report, [ok()] * 3, "Move")
                frames_total += 6
            frames = []
            answers = []
            for _ in range(rng.randrange(100, 2000)):
                k = rng.random()
                if k < 0.6:
                    frames.append(cmd(GET_POS, rng.randrange(3)))
                    answers.append(None)
                elif k < 0.8:
                    pin = rng.randrange(4)
                    frames.append(cmd(SET_PIN, pin, rng.randrange(2)))
                    answers.append(ok())
                elif k < 0.95:
                    frames.append(cmd(GET_PIN, rng.randrange(8)))
                    answers.append(None)
                else:
                    frames.append(bad_frame(rng, "flip"))
                    answers.append(err(E1))
                    provoked["sent_E1"] += 1
            exchange(port, frames, report, answers, "soak")
            frames_total += len(frames)
            if now >= next_sample:
                next_sample = now + 10.0
                samples.append({"t": round(now - t0, 1), "rss_kib": d.rss_kib(), "fds": d.fds()})
        del base
        last = d.status()["link"]["counters"]
        grown = {
            k: last[k] - first.get(k, 0)
            for k in last
            if (
                k.endswith("_errors")
                or k.startswith("sent_E")
                or k in ("gap_discards", "link_errors", "responses_dropped", "held_overflow")
            )
            and last[k] != first.get(k, 0)
        }
        stalls = report.host_stalls - stalls_before
        for k, v in grown.items():
            allowed = provoked["sent_E1"] if k in ("sent_E1", "checksum_errors") else 0
            if v != allowed and not stalls:  # a host stall makes a real gap: counts differ
                report.violation(f"soak: counter {k} grew by {v}, the traffic provoked {allowed}")
        elapsed = time.monotonic() - t0
        rss = [s["rss_kib"] for s in samples]
        fds = [s["fds"] for s in samples]
        # Flat: after the first minute, RSS grows by less than 2 MiB and fds not at all.
        settled = [s for s in samples if s["t"] >= min(60.0, seconds / 2)]
        if settled and max(s["rss_kib"] for s in settled) - settled[0]["rss_kib"] > 2048:
            report.violation(
                f"soak: RSS grew from {settled[0]['rss_kib']} to "
                f"{max(s['rss_kib'] for s in settled)} KiB"
            )
        # Flat: no growth between the first and the last settled sample; one fd more or less
        # in a sample is the state writer's file or a status connection caught in passing.
        if settled and max(s["fds"] for s in settled) > min(s["fds"] for s in settled) + 1:
            report.violation(f"soak: open fds grew: {fds}")
        report.figures["soak"] = {
            "seconds": round(elapsed, 1),
            "frames": frames_total,
            "frames_per_s": round(frames_total / elapsed),
            "rss_kib": [min(rss), max(rss)],
            "fds": [min(fds), max(fds)],
            "samples": samples,
            "counters_grown": grown,
            "provoked": provoked,
            "host_stalls": stalls,
        }
        print(
            f"  soak: {frames_total} frames in {elapsed:.0f} s "
            f"({frames_total / elapsed:.0f}/s), RSS {min(rss)}..{max(rss)} KiB, "
            f"fds {min(fds)}..{max(fds)}",
            flush=True,
        )
    finally:
        port.close()
        if d.alive():
            d.terminate()


# -- part 5: a new host while the old one's WaitMoved is held ---------------------------
def part_reconnect(workdir: Path, cycles: int, seed: int, report: Report) -> None:
    """A host closes the port in the middle of a WaitMoved, with frames kept behind it, and
    a new host opens it at once (or within 20 ms): the new host must read only its own
    answers, exactly, long before the old WaitMoved could end; the old session's kept
    commands must never run (a SetPin, a MoveTo), while a StopMove among them is carried
    out; its partial frame must not join the new host's first frame."""
    rng = random.Random(seed)
    state = workdir / "state"
    d = Daemon(workdir, state).start()
    _current_daemon[:] = [d]
    first_s: list[float] = []
    expected = {"wait": 0, "held": 0, "discarded": 0}
    t0 = time.monotonic()
    try:
        motion = [0]  # motor 0's target: where it is at start
        for cycle in range(cycles):
            reconnect_cycle(d, rng, cycle, report, first_s, expected, motion)
        counters = d.status()["link"]["counters"]
    finally:
        if d.alive():
            d.terminate()
    for key, name in (
        ("wait", "responses_dropped_wait"),
        ("held", "responses_dropped_held"),
        ("discarded", "held_discarded"),
    ):
        if counters.get(name) != expected[key]:
            report.violation(
                f"reconnect: the daemon counts {name} = {counters.get(name)}, "
                f"the harness made {expected[key]}"
            )
    first_s.sort()
    report.figures["reconnect"] = {
        "cycles": cycles,
        "seconds": round(time.monotonic() - t0, 1),
        "first_answer_ms": {
            "p50": round(first_s[len(first_s) // 2] * 1000, 3),
            "p99": round(first_s[min(len(first_s) - 1, int(0.99 * len(first_s)))] * 1000, 3),
            "max": round(first_s[-1] * 1000, 3),
        },
        "counters": {
            k: v
            for k, v in counters.items()
            if k.startswith(("responses_dropped", "held_", "peer_", "stops_while"))
        },
    }
    print(
        f"  reconnect: {cycles} cycles, the new host's first answer after "
        f"{report.figures['reconnect']['first_answer_ms']} ms"
    )


def reconnect_cycle(
    d: Daemon,
    rng: random.Random,
    cycle: int,
    report: Report,
    first_s: list[float],
    expected: dict[str, int],
    motion: list[int],
) -> None:
    """One host restarted during a WaitMoved (``motion``: motor 0's target, kept across
    cycles)."""
    what = f"reconnect cycle {cycle}"
    old = Port(d.pty)
    try:
        # what the new host must find unchanged: the output pins, motor 1 (at rest)
        exchange(old, [cmd(STOP, 1, 1)], report, [ok()], what)
        wait_idle(old, 1, report)
        levels = [ask(old, cmd(GET_PIN, pin), report, what) for pin in range(4)]
        pos1 = ask(old, cmd(GET_POS, 1), report, what)
        # motor 0 moving for a second at least (1000 step/s, between 1000 and 6000, clear
        # of the end stops; a new move once the last one is near its end); motor 2
        # running, to be stopped
        here = pos_of(ask(old, cmd(GET_POS, 0), report, what))
        if abs(motion[0] - here) < 1000:
            wait_idle(old, 0, report)
            motion[0] = 1000 if motion[0] > 1000 else 6000
            exchange(old, [cmd(MOVE_TO, 0, 1, motion[0], 10, 0, 0)], report, [ok()], what)
        stop2 = rng.random() < 0.5
        if stop2:
            exchange(old, [cmd(MOVE, 2, 1, 1, 0, 0)], report, [ok()], what)
        # the WaitMoved, and frames kept behind it: none of them may ever be executed
        # but a StopMove; beyond 16 places they are answered E0 (never sent either)
        kept: list[bytes] = []
        for _ in range(rng.randint(0, 24)):
            choice = rng.random()
            if choice < 0.3:
                pin = rng.randrange(4)
                kept.append(cmd(SET_PIN, pin, 0 if levels[pin][1] else 1))
            elif choice < 0.5:
                kept.append(cmd(MOVE_TO, 1, 1, pos_of(pos1) + 500, 10, 0, 0))
            elif choice < 0.7:
                kept.append(cmd(GET_POS, 1))
            elif choice < 0.85:
                kept.append(cmd(IS_READY, 2))
            else:  # a frame that fails its checks (one flipped bit)
                flipped = bytearray(cmd(GET_POS, 0))
                flipped[rng.randrange(10)] ^= 1 << rng.randrange(8)
                kept.append(bytes(flipped))
        if stop2:
            kept.insert(rng.randint(0, len(kept)), cmd(STOP, 2, 1))
        frames_before = d.status()["link"]["counters"]["frames"]
        partial = cmd(GET_POS, 0)[: rng.randint(0, 9)]
        old.write(cmd(WAIT, 0, 30_000) + b"".join(kept) + partial)
        deadline = time.monotonic() + RESPONSE_TIMEOUT_S
        while d.status()["link"]["counters"]["frames"] < frames_before + 1 + len(kept):
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what}: the daemon did not take the old host's frames")
            time.sleep(0.002)
        if d.status()["link"]["waiting"] is not True:
            report.violation(f"{what}: the WaitMoved was not held (motor 0 not moving?)")
        expected["wait"] += 1
        expected["held"] += len(kept)
        places = 0
        for frame in kept:
            if frame[0] == STOP and frame_valid(frame):
                continue
            places += 1
            if places <= 16 and frame_valid(frame):
                expected["discarded"] += 1
    finally:
        old.close()  # without reading: the WaitMoved's answer and the kept ones are owed
    if rng.random() < 0.5:
        time.sleep(rng.uniform(0, 0.02))
    new = Port(d.pty)
    try:
        queries = [cmd(IS_READY, 1)] + [cmd(GET_PIN, pin) for pin in range(4)] + [cmd(GET_POS, 1)]
        want = [ok(b"\x01\0\0"), *levels, pos1]
        if stop2:  # the kept StopMove stopped it on arrival (a Move runs until stopped);
            # its stop is confirmed a moment later on a loaded machine: a WaitMoved, not
            # IsReady, asks whether it stopped
            queries.append(cmd(WAIT, 2, 5000))
            want.append(ok())
        t = time.monotonic()
        new.write(b"".join(queries))
        got = new.take(5, timeout=2.0)
        first_s.append(time.monotonic() - t)
        got += new.take(5 * (len(queries) - 1), timeout=2.0)
        if got != b"".join(want):
            report.violation(
                f"{what}: the new host read {got.hex(' ')}, not its own answers "
                f"{b''.join(want).hex(' ')}"
            )
        if extra := new.extra(0.05):
            report.violation(f"{what}: the new host read more than its answers: {extra.hex()}")
    finally:
        new.close()


# -- part 4: the state directory turns read-only ---------------------------------------
def part_faults(workdir: Path, report: Report) -> None:
    """SaveHome/SaveWayPoint while the state directory is read-only must answer E4 (the
    state cannot be written) and change nothing; the daemon keeps serving; once writable
    again, saves work, and a kill -9 loses none of the acknowledged ones.

    The directory turns read-only under the running daemon by a read-only bind mount of it
    onto itself (files the daemon already holds open stay as they are, as on a filesystem
    that the kernel remounted read-only after an error); needs root."""
    state = workdir / "state"
    state.mkdir()
    answers: dict[str, str] = {}
    d = Daemon(workdir, state).start()
    port = Port(d.pty)
    read_only = False
    try:
        exchange(port, [cmd(MOVE_TO, 0, 1, 500, 0, 0, 0)], report, [ok()], "MoveTo")
        wait_idle(port, 0, report)
        exchange(port, [cmd(SAVE_HOME, 0), cmd(SAVE_WP, 0)], report, [ok(), ok()], "saves")
        exchange(port, [cmd(MOVE_TO, 0, 1, 700, 0, 0, 0)], report, [ok()], "MoveTo")
        wait_idle(port, 0, report)
        time.sleep(0.2)  # the motor's rest has been written
        why = make_read_only(state)
        if why:
            report.figures["faults"] = {"state_dir_read_only": f"skipped: {why}"}
            return
        read_only = True
        for name, frame in (("SaveHome", cmd(SAVE_HOME, 0)), ("SaveWayPoint", cmd(SAVE_WP, 0))):
            r = ask(port, frame, report, name)
            answers[name + " read-only"] = r.hex()
            if r != err(E4):
                report.violation(
                    f"faults: {name} on a read-only state directory answered "
                    f"{r.hex()}, not E4 (PROTOCOL.md §4: ACK only once written)"
                )
        r = ask(port, cmd(IS_READY, 0), report, "IsReady")
        if r != ok(b"\x01\0\0"):
            report.violation(f"faults: IsReady after the failed saves answered {r.hex()}")
        subprocess.run(["umount", str(state)], check=True, capture_output=True)
        read_only = False
        r = ask(port, cmd(SAVE_WP, 0), report, "SaveWayPoint")
        answers["SaveWayPoint writable again"] = r.hex()
        expected_wps = 2 if r == ok(b"\x01\0\0") else 1
        if r[:1] != b"\x01":
            report.violation(f"faults: SaveWayPoint once writable again answered {r.hex()}")
        d.kill()
        port.close()
        d = Daemon(workdir, state).start()
        port = Port(d.pty)
        for n in range(expected_wps):
            if ask(port, cmd(MOVE_TO_WP, 0, n, 0, 0, 0), report, "MoveToWayPoint") == err(E6):
                report.violation(f"faults: acknowledged waypoint {n} lost")
            wait_idle(port, 0, report)
        if ask(port, cmd(MOVE_TO_WP, 0, expected_wps, 0, 0, 0), report, "") != err(E6):
            report.violation("faults: a waypoint whose save was refused exists")
        exchange(port, [cmd(GO_HOME, 0)], report, [ok()], "GoHome")
        wait_idle(port, 0, report)
        home = pos_of(ask(port, cmd(GET_POS, 0), report, "GetAbsPos"))
        answers["home after restart"] = str(home)
        if home != 500:
            report.violation(f"faults: home is {home} after the refused SaveHome, not 500")
    finally:
        port.close()
        d.kill()
        if read_only:
            subprocess.run(["umount", str(state)], capture_output=True)
    report.figures["faults"] = {"state_dir_read_only": answers}


def make_read_only(path: Path) -> str | None:
    """Bind-mount ``path`` read-only onto itself; None, or why it could not be done."""
    steps = (
        ["mount", "--bind", str(path), str(path)],
        ["mount", "-o", "remount,bind,ro", str(path)],
    )
    for i, step in enumerate(steps):
        done = subprocess.run(step, capture_output=True, text=True)
        if done.returncode != 0:
            if i:
                subprocess.run(["umount", str(path)], capture_output=True)
            return f"{' '.join(step)}: {done.stderr.strip()} (needs root)"
    return None


PARTS: dict[str, Callable[[Path, argparse.Namespace, Report], None]] = {
    "faults": lambda w, a, r: part_faults(w, r),
    "frames": lambda w, a, r: part_frames(w, a.frames, a.seed, r),
    "kill": lambda w, a, r: part_kill(w, a.kills, a.seed, r),
    "reconnect": lambda w, a, r: part_reconnect(w, a.reconnects, a.seed, r),
    "soak": lambda w, a, r: part_soak(w, a.soak_s, a.seed, r),
}


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument(
        "--parts",
        default="frames,kill,reconnect,faults,soak",
        help="comma-separated: " + ", ".join(PARTS),
    )
    p.add_argument("--frames", type=int, default=1_000_000)
    p.add_argument("--kills", type=int, default=100)
    p.add_argument("--reconnects", type=int, default=200)
    p.add_argument("--soak-s", type=float, default=600.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--quick",
        action="store_true",
        help="20,000 frames, 10 kill cycles, 20 reconnects, a 30 s soak",
    )
    p.add_argument("--json", metavar="FILE", help="write the figures and violations here")
    args = p.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(2))  # so that daemons get cleaned up
    rt = Port.realtime_writes
    if args.quick:
        args.frames, args.kills, args.reconnects, args.soak_s = 20_000, 10, 20, 30.0
    report = Report()
    report.figures["host_realtime"] = rt
    with tempfile.TemporaryDirectory(prefix="motorctl-robustness-") as tmp:
        for name in args.parts.split(","):
            print(f"== {name}", flush=True)
            work = Path(tmp) / name
            work.mkdir()
            try:
                PARTS[name](work, args, report)
            except (RuntimeError, TimeoutError, OSError) as exc:
                report.violation(f"{name}: {exc}")
            stderr = work / "motorctld.stderr"
            log_text = stderr.read_text() if stderr.exists() else ""
            if "Traceback" in log_text:
                report.violation(f"{name}: a traceback in the daemon's log")
            if log_text:
                report.figures.setdefault("daemon_log_tail", {})[name] = log_text[-3000:]
    report.figures["host_stalls_skipped"] = report.host_stalls
    report.figures["frames_in_skipped_segments"] = report.skipped_frames
    result = {"figures": report.figures, "violations": report.violations}
    print(json.dumps(result, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 1 if report.violations else 0


if __name__ == "__main__":
    raise SystemExit(main())
