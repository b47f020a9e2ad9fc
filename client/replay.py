"""``motorctl replay FILE --port P``: play a recording's host side against a device and
compare every answer with the recorded one (docs/trace.md, "Replay").

Over 500 lines on purpose: one command, whose player and comparison rules (below) are
read together; the rules are most of it, and each is a short function.

What is sent: the recorded host -> device byte runs, byte for byte and cut as recorded (so
the device frames them as the original did). When: each run waits for what it waited for in
the recording (the answers the host had received before it, and the run before it), then
the recorded pause after that (``--fast``: no pause, except silences inside a partial frame,
which the gap rule needs). A host that reacted to an answer is thus replayed reacting to the
device's answer, however fast or slow that comes.

How answers are compared (frame by frame, paired in order as the protocol answers):

- byte for byte, for every answer that does not depend on timing;
- a GetAbsPos answered while its motor was moving in the recording: within
  ``position_tolerance`` + v x ``time_tolerance`` steps, v being the motor's speed around
  that read in the recording (from its neighbouring position reads); with ``--fast`` (the
  timing is not kept) anywhere within the positions that motion covered in the recording
  (its start, its reads, its MoveTo target, its first position at rest) +-
  ``position_tolerance``;
- an IsReady answered while its motor was moving: a differing answer is timing, not a
  difference, when the recorded answers of that motor change within ``time_tolerance`` of
  it (always with ``--fast``);
- WaitMoved: its answer byte for byte, and (not with ``--fast``) how long it was held:
  within ``time_tolerance`` + 2 % of the recorded time.

A motor's state in the recording is read off the answers: a motion command's ACK starts a
motion; IsReady TRUE, a WaitMoved's ACK, a hard StopMove's ACK or an E4 end it; at the
start of the recording motors are taken to be at rest (record from rest, replay from the
same state: positions, homes and waypoints).

Runs on the caller's thread; blocks in ``poll()`` on the port.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import serial

from motorctl.client.recording import TraceFileError
from motorctl.client.trace import (
    ANSWER,
    Conversation,
    Frame,
    Row,
    add_settings_options,
    analyse,
    answer_text,
    one_link,
    warn,
)
from motorctl.protocol.capture import CaptureInfo, Direction, Record
from motorctl.protocol.codec import (
    FRAME_LEN,
    POS_MAX,
    POS_MIN,
    RESPONSE_LEN,
    GetAbsPos,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    StopMove,
    WaitMoved,
    describe,
)
from motorctl.protocol.framing import Framer

TIME_TOLERANCE_S = 0.05
POSITION_TOLERANCE = 2
WAIT_RELATIVE = 0.02
ANSWER_TIMEOUT_S = 5.0
LINGER_S = 0.2  # after the last answer: time for answers the recording did not have

MOTION = (InitMove, MoveTo, Move, GoHome, MoveToWayPoint)


# --- the plan --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Send:
    """One host run: its bytes, when it was recorded (s after the first run), the answers
    received before it, and whether a partial frame was pending before it (its pause then
    matters to framing, even with ``--fast``)."""

    data: bytes
    at_s: float
    need: int
    framing: bool


def plan(records: list[Record], info: CaptureInfo) -> list[Send]:
    framer = Framer(info.frame_gap_ms / 1000.0)
    out_bytes = 0
    last_in_t: int | None = None
    first: int | None = None
    sends: list[Send] = []
    for rec in records:
        if rec.direction is Direction.TO_HOST:
            out_bytes += len(rec.data)
            continue
        if first is None:
            first = rec.ts_ns
        framing = framer.pending > 0
        if last_in_t is not None and framing:
            framer.idle((rec.ts_ns - last_in_t) / 1e9)
        framer.feed(rec.data)
        sends.append(Send(rec.data, (rec.ts_ns - first) / 1e9, out_bytes // RESPONSE_LEN, framing))
        last_in_t = rec.ts_ns
    return sends


# --- playing ---------------------------------------------------------------------------------


class ReplayAborted(Exception):
    """The device stopped answering; the message names the frame."""


class Player:
    """Writes the plan to ``fd`` and collects what comes back, with times."""

    def __init__(
        self, fd: int, fast: bool, answer_timeout: float, rtts: list[float | None]
    ) -> None:
        self.fd = fd
        self.fast = fast
        self.answer_timeout = answer_timeout
        self.rtts = rtts  # recorded round trip of each frame's answer (None: unanswered)
        self.poller = select.poll()
        self.poller.register(fd, select.POLLIN)
        self.records: list[Record] = []
        self.answer_times: list[float] = []
        self.received = 0
        self.frames_sent = 0
        self.frame_sent_at: list[float] = []
        self.t0 = time.monotonic()
        self.wall0 = time.time_ns()
        self._last_progress = self.t0

    def _ts(self, t: float) -> int:
        return self.wall0 + round((t - self.t0) * 1e9)

    def _read(self, until: float) -> bool:
        """Read what comes until ``until`` (monotonic); False if nothing came."""
        left = until - time.monotonic()
        if not self.poller.poll(max(0.0, left) * 1000):
            return False
        t = time.monotonic()
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return True
        if not data:
            raise ReplayAborted("the port was closed")
        self.records.append(Record(self._ts(t), Direction.TO_HOST, data))
        before = self.received // RESPONSE_LEN
        self.received += len(data)
        for _ in range(self.received // RESPONSE_LEN - before):
            self.answer_times.append(t)
        return True

    def _await_answers(self, count: int) -> None:
        """Until ``count`` answers came; ReplayAborted when one does not come in time."""
        while len(self.answer_times) < count:
            k = len(self.answer_times)  # the frame whose answer is awaited
            sent = self.frame_sent_at[k] if k < len(self.frame_sent_at) else time.monotonic()
            rtt = self.rtts[k] if k < len(self.rtts) and self.rtts[k] is not None else 0.0
            deadline = max(sent, self._last_progress) + (rtt or 0.0) + self.answer_timeout
            if not self._read(deadline) and time.monotonic() >= deadline:
                raise ReplayAborted(
                    f"no answer to frame #{k + 1} within {deadline - sent:.1f} s of sending it"
                )
            self._last_progress = time.monotonic()

    def play(self, sends: list[Send], expected_answers: int) -> str | None:
        """Play; None when every expected answer came, else why it stopped.

        Each run is due at its recorded time on a schedule that starts with the first run;
        it also waits for the answers the host had before it, and when those come later
        than that, the rest of the schedule moves by as much (``shift``). So a pause is
        neither lost nor stretched by the replaying host's own latency adding up over
        many commands. With ``fast`` a run is due as soon as its answers are in, except
        for a pause inside a partial frame (the gap rule needs it), kept as recorded."""
        self._last_progress = time.monotonic()
        start = time.monotonic()
        shift = 0.0
        pending = 0
        prev_at = 0.0
        last_sent = start
        try:
            for s in sends:
                self._await_answers(s.need)
                ready = time.monotonic()
                if not self.fast:
                    due = start + shift + s.at_s
                elif s.framing:
                    due = last_sent + (s.at_s - prev_at)
                else:
                    due = ready
                while time.monotonic() < due:
                    self._read(due)
                self._write(s.data)
                last_sent = time.monotonic()
                if not self.fast and ready > start + shift + s.at_s:
                    shift = ready - start - s.at_s  # the answers were late: so is the rest
                prev_at = s.at_s
                self.records.append(Record(self._ts(last_sent), Direction.TO_DEVICE, s.data))
                pending += len(s.data)
                for _ in range(pending // FRAME_LEN):
                    self.frame_sent_at.append(last_sent)
                pending %= FRAME_LEN
                self._last_progress = last_sent
            self._await_answers(expected_answers)
        except ReplayAborted as exc:
            return str(exc)
        end = time.monotonic() + LINGER_S
        while time.monotonic() < end:
            self._read(end)
        return None

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            view = view[n:]


# --- comparing -------------------------------------------------------------------------------


@dataclass
class Tolerances:
    time_s: float = TIME_TOLERANCE_S
    position: int = POSITION_TOLERANCE
    fast: bool = False


@dataclass
class Verdict:
    frame: int
    t_s: float
    command: str
    recorded: str
    replayed: str
    result: str  # "exact", "tolerated", "differs", "not compared"
    why: str = ""

    def line(self) -> str:
        return (
            f"frame #{self.frame} at {self.t_s:.6f} s {self.command}: recorded "
            f"{self.recorded}, replayed {self.replayed}" + (f" ({self.why})" if self.why else "")
        )


@dataclass
class Episode:
    """One motion of one motor in the recording: the positions it is known to cover."""

    positions: list[int] = field(default_factory=list)
    start_known: bool = False
    target: int | None = None  # a MoveTo's


@dataclass
class MotorHistory:
    """Per frame of the recording: was the command's motor (possibly) moving, in which
    motion; per motor: its position reads and IsReady answers with times."""

    moving: dict[int, Episode] = field(default_factory=dict)  # frame number -> its motion
    reads: dict[int, list[tuple[int, int]]] = field(default_factory=dict)  # motor -> (t, pos)
    ready: dict[int, list[tuple[int, bool]]] = field(default_factory=dict)  # motor -> (t, v)


def history(conv: Conversation) -> MotorHistory:
    h = MotorHistory()
    current: dict[int, Episode | None] = {}
    last_pos: dict[int, int] = {}
    for f in conv.frames:
        cmd, ans = f.command, f.answer
        motor = getattr(cmd, "motor", None)
        if cmd is None or ans is None or ans.response is None or motor is None:
            continue
        resp = ans.response
        episode = current.get(motor)
        if episode is not None:
            h.moving[f.number] = episode
        if isinstance(cmd, GetAbsPos) and resp.ack:
            pos = resp.as_position
            h.reads.setdefault(motor, []).append((ans.t_ns, pos))
            last_pos[motor] = pos
            if episode is not None:
                episode.positions.append(pos)
        if isinstance(cmd, IsReady) and resp.ack:
            h.ready.setdefault(motor, []).append((ans.t_ns, resp.as_bool))
        if not resp.ack:
            if resp.payload[0] == 0xE4:
                _end(current, last_pos, motor)
            continue
        if isinstance(cmd, MOTION):
            if episode is None:
                episode = current[motor] = Episode()
                if motor in last_pos:
                    episode.positions.append(last_pos[motor])
                    episode.start_known = True
            if isinstance(cmd, MoveTo):
                episode.positions.append(cmd.position)
                episode.target = cmd.position
        elif (
            (isinstance(cmd, StopMove) and cmd.hard)
            or isinstance(cmd, WaitMoved)
            or (isinstance(cmd, IsReady) and resp.as_bool)
        ):
            _end(current, last_pos, motor)
    return h


def _end(current: dict[int, Episode | None], last_pos: dict[int, int], motor: int) -> None:
    """A motion ended: where it ended is known only from the next read."""
    if current.get(motor) is not None:
        last_pos.pop(motor, None)
    current[motor] = None


def _speed_around(reads: list[tuple[int, int]], t_ns: int) -> float:
    """The largest |dpos|/dt between the read at ``t_ns`` and its neighbours (step/s)."""
    times = [t for t, _ in reads]
    if t_ns not in times:
        return 0.0
    i = times.index(t_ns)
    v = 0.0
    for j in (i - 1, i + 1):
        if 0 <= j < len(reads) and reads[j][0] != t_ns:
            v = max(v, abs(reads[j][1] - reads[i][1]) / (abs(reads[j][0] - t_ns) / 1e9))
    return v


def _first_pos_after(reads: list[tuple[int, int]], t_ns: int) -> int | None:
    return next((p for t, p in reads if t > t_ns), None)


def compare(rec: Conversation, rep: Conversation, tol: Tolerances, t0: int) -> list[Verdict]:
    h = history(rec)
    out: list[Verdict] = []
    rep_frames = {f.number: f for f in rep.frames}
    for f in rec.frames:
        name = describe(f.command) if f.command is not None else f"bad frame {f.data.hex(' ')}"
        t_s = (f.t_ns - t0) / 1e9
        a = f.answer
        g = rep_frames.get(f.number)
        b = g.answer if g is not None else None
        if a is None:
            out.append(
                Verdict(
                    f.number,
                    t_s,
                    name,
                    "no answer (the recording ends)",
                    _show(b, f),
                    "not compared",
                )
            )
            continue
        if b is None:
            out.append(Verdict(f.number, t_s, name, _show(a, f), "no answer", "differs"))
            continue
        out.append(_judge(f, a, b, h, tol, t_s, name))
    for g in rep.frames[len(rec.frames) :]:
        out.append(
            Verdict(
                g.number,
                0.0,
                describe(g.command) if g.command else "bad frame",
                "not in the recording",
                _show(g.answer, g),
                "differs",
            )
        )
    return out


def _show(row: Row | None, f: Frame | None) -> str:
    if row is None:
        return "no answer"
    text = answer_text(f.command if f else None, row.response) if row.response else row.text
    return f"{row.data.hex(' ')} ({text})"


def _judge(
    f: Frame, a: Row, b: Row, h: MotorHistory, tol: Tolerances, t_s: float, name: str
) -> Verdict:
    cmd = f.command
    v = Verdict(f.number, t_s, name, _show(a, f), _show(b, f), "exact")
    if a.data == b.data:
        if (
            isinstance(cmd, WaitMoved)
            and not tol.fast
            and a.rtt_ns is not None
            and b.rtt_ns is not None
        ):
            allowed = tol.time_s + WAIT_RELATIVE * a.rtt_ns / 1e9
            diff = abs(b.rtt_ns - a.rtt_ns) / 1e9
            v.recorded += f" after {a.rtt_ns / 1e9:.3f} s"
            v.replayed += f" after {b.rtt_ns / 1e9:.3f} s"
            if diff > allowed:
                v.result, v.why = (
                    "differs",
                    f"held {diff * 1000:.0f} ms longer or shorter "
                    f"than recorded; tolerance {allowed * 1000:.0f} ms",
                )
        return v
    episode = h.moving.get(f.number)
    both_ack = (
        a.kind == ANSWER
        and b.kind == ANSWER
        and a.response is not None
        and b.response is not None
        and a.response.ack
        and b.response.ack
    )
    if isinstance(cmd, GetAbsPos) and episode is not None and both_ack:
        assert a.response is not None and b.response is not None
        pa, pb = a.response.as_position, b.response.as_position
        reads = h.reads.get(cmd.motor, [])
        if tol.fast:
            known = list(episode.positions)
            after = _first_pos_after(reads, a.t_ns)
            if after is not None:
                known.append(after)
            lo, hi = min(known) - tol.position, max(known) + tol.position
            if not episode.start_known and episode.target is not None:
                # where it started is not in the recording: anywhere behind its target
                if episode.target >= pa:
                    lo = POS_MIN
                else:
                    hi = POS_MAX
            if lo <= pb <= hi:
                v.result, v.why = (
                    "tolerated",
                    f"moving: within {lo}..{hi}, the positions "
                    "that motion covered in the recording (--fast keeps no timing)",
                )
            else:
                v.result, v.why = (
                    "differs",
                    f"moving, but outside {lo}..{hi}, the "
                    "positions that motion covered in the recording",
                )
            return v
        speed = _speed_around(reads, a.t_ns)
        allowed = tol.position + speed * tol.time_s
        if abs(pb - pa) <= allowed:
            v.result = "tolerated"
            v.why = (
                f"moving at about {speed:.0f} step/s: {abs(pb - pa)} steps off, "
                f"tolerance {allowed:.0f}"
            )
        else:
            v.result = "differs"
            v.why = (
                f"moving at about {speed:.0f} step/s: {abs(pb - pa)} steps off, more "
                f"than the tolerance {allowed:.0f}"
            )
        return v
    if isinstance(cmd, IsReady) and episode is not None and both_ack:
        readies = h.ready.get(cmd.motor, [])
        assert a.response is not None
        mine = a.response.as_bool
        near = any(val != mine and abs(t - a.t_ns) / 1e9 <= tol.time_s for t, val in readies)
        if tol.fast or near:
            v.result = "tolerated"
            v.why = (
                "the motor was moving: timing (the recorded answers change within "
                f"{tol.time_s * 1000:.0f} ms)"
                if not tol.fast
                else "the motor was moving: timing (--fast keeps no timing)"
            )
            return v
    v.result = "differs"
    return v


# --- command line ----------------------------------------------------------------------------


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="play a recording's host side against a device and compare answers",
        description="Send the host -> device bytes of a trace file (motorctld --trace, "
        "motorctl tap) to a device as recorded, with the recorded pauses or --fast, and "
        "compare every answer with the recorded one: byte for byte, except positions read "
        "while a motor moved, IsReady of a moving motor and how long WaitMoved was held, "
        "which are compared within the tolerances (docs/trace.md). Prints a diff report; "
        "exit status 0 when every answer matches, 1 on a difference, 2 on an error.",
    )
    p.add_argument("files", nargs="+", type=Path, metavar="FILE")
    p.add_argument(
        "-p",
        "--port",
        default=argparse.SUPPRESS,
        metavar="PATH",
        help="the device's port (default: $MOTORCTL_PORT)",
    )
    p.add_argument(
        "--fast",
        action="store_true",
        help="no pauses: each run goes as soon as the answers it waited for came",
    )
    p.add_argument(
        "--time-tolerance-ms",
        type=float,
        default=TIME_TOLERANCE_S * 1000,
        metavar="MS",
        help="timing tolerance (default 50)",
    )
    p.add_argument(
        "--position-tolerance",
        type=int,
        default=POSITION_TOLERANCE,
        metavar="STEPS",
        help="position tolerance of moving motors (default 2)",
    )
    p.add_argument(
        "--answer-timeout",
        type=float,
        default=ANSWER_TIMEOUT_S,
        metavar="S",
        help="an answer later than recorded by this much ends the replay (default 5)",
    )
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="also list the answers matched within a tolerance",
    )
    p.add_argument("--json", action="store_true", help="the report as JSON")
    add_settings_options(p)


def run(args: argparse.Namespace) -> int:
    if not args.port:
        print("error: no device port: pass --port PATH or set MOTORCTL_PORT", file=sys.stderr)
        return 2
    try:  # the reader motorctl trace uses: the same files accepted, the same problems named
        recording, link, info = one_link(
            args.files, args.interface, args.trace_checksum, args.frame_gap_ms
        )
    except (TraceFileError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    warn(recording.problems)
    records = link.records
    if not any(r.direction is Direction.TO_DEVICE for r in records):
        named = ", ".join(map(str, args.files))
        print(
            f"error: nothing to replay: {named} hold{'s' if len(args.files) == 1 else ''} no "
            "host -> device bytes" + (" (see the warnings above)" if recording.problems else ""),
            file=sys.stderr,
        )
        return 2
    recorded = analyse(records, info)
    sends = plan(records, info)
    rtts: list[float | None] = [
        None if f.answer is None or f.answer.rtt_ns is None else f.answer.rtt_ns / 1e9
        for f in recorded.frames
    ]
    expected = sum(1 for f in recorded.frames if f.answer is not None)
    try:
        port = serial.Serial(args.port, args.baud, timeout=0, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as exc:
        print(f"error: cannot open {args.port}: {exc}", file=sys.stderr)
        return 2
    try:
        os.set_blocking(port.fileno(), False)
        player = Player(port.fileno(), args.fast, args.answer_timeout, rtts)
        aborted = player.play(sends, expected)
    finally:
        port.close()
    replayed = analyse(player.records, info)
    tol = Tolerances(args.time_tolerance_ms / 1000.0, args.position_tolerance, args.fast)
    t0 = records[0].ts_ns
    verdicts = compare(recorded, replayed, tol, t0)
    extra = [r for r in replayed.rows if r.kind == "extra_answer"]
    differs = [v for v in verdicts if v.result == "differs"]
    tolerated = [v for v in verdicts if v.result == "tolerated"]
    exact = sum(1 for v in verdicts if v.result == "exact")
    failed = bool(differs or extra or aborted)
    if args.json:
        doc = {
            "file": [str(f) for f in args.files],
            "port": args.port,
            "fast": args.fast,
            "tolerances": {
                "time_ms": tol.time_s * 1000,
                "position_steps": tol.position,
                "wait_relative": WAIT_RELATIVE,
            },
            "frames": len(recorded.frames),
            "exact": exact,
            "tolerated": len(tolerated),
            "differs": len(differs),
            "extra_answers": len(extra),
            "aborted": aborted,
            "verdicts": [v.__dict__ for v in verdicts if v.result != "exact"],
            "problems": recording.problems,
            "ok": not failed,
        }
        print(json.dumps(doc, indent=1))
        return 1 if failed else 0
    for v in verdicts:
        if v.result == "differs":
            print(f"DIFF  {v.line()}")
        elif v.result == "tolerated" and args.verbose:
            print(f"near  {v.line()}")
    for r in extra:
        print(f"DIFF  an answer more than the recording had: {r.data.hex(' ')}")
    if aborted:
        print(f"DIFF  replay stopped: {aborted}")
    print(
        f"replay of {len(recorded.frames)} frames against {args.port}"
        f"{' (--fast)' if args.fast else ''}: {exact} answers byte-exact, {len(tolerated)} "
        f"within tolerance, {len(differs) + len(extra) + (1 if aborted else 0)} differ"
        + ("" if failed else ": no difference")
    )
    return 1 if failed else 0
