"""``motorctl replay FILE --port P``: play a recording's host side against a device and
compare every answer with the recorded one (docs/trace.md, "Replay").

What is sent: the recorded host -> device byte runs, byte for byte and cut as recorded (so
the device frames them as the original did). When: each run waits for what it waited for in
the recording (the answers the host had received before it, and the run before it), then
the recorded pause after that (``--fast``: no pause, except silences inside a partial frame,
which the gap rule needs). A host that reacted to an answer is thus replayed reacting to the
device's answer, however fast or slow that comes. The player notes when it sent each frame
(the write of its last byte began) and how late that was after it was due: the pacing error.

How the answers are judged, from those times: :mod:`motorctl.client.judge`.

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

from motorctl.client.arguments import number_in, whole_in
from motorctl.client.conversation import Conversation, analyse
from motorctl.client.judge import (
    POSITION_TOLERANCE,
    SLIDE_TOLERANCE,
    TIME_TOLERANCE_S,
    Tolerances,
    Verdict,
    compare,
)
from motorctl.client.motions import windows
from motorctl.client.port_errors import not_a_port, open_error
from motorctl.client.recording import Recording, TraceFileError
from motorctl.client.trace import add_settings_options, one_link, warn
from motorctl.protocol.capture.format import CaptureInfo, Direction, Record
from motorctl.protocol.codec import RESPONSE_LEN
from motorctl.protocol.framing import Framer

ANSWER_TIMEOUT_S = 5.0
LINGER_S = 0.2  # after the last answer: time for answers the recording did not have


# --- the plan --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Send:
    """One host run: its bytes, when it was recorded (s after the first run), the answers
    received before it, whether a partial frame was pending before it (its pause then
    matters to framing, even with ``--fast``), and how many frames it completes."""

    data: bytes
    at_s: float
    need: int
    framing: bool
    frames: int = 0


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
        done = len(framer.feed(rec.data))
        sends.append(
            Send(rec.data, (rec.ts_ns - first) / 1e9, out_bytes // RESPONSE_LEN, framing, done)
        )
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
        self.frame_sent_at: list[float] = []  # when each frame's last byte was written
        self.sent_ns: dict[int, int] = {}  # frame number -> its write began (records' clock)
        self.late: list[float] = []  # each run: how late it was sent after it was due (s)
        self.frame_late: dict[int, float] = {}  # frame number -> its run's lateness (s)
        self.aborted: str | None = None
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
        for a pause inside a partial frame (the gap rule needs it), kept as recorded.
        How late each run went after it was due is its pacing error (``late``)."""
        self._last_progress = time.monotonic()
        start = time.monotonic()
        shift = 0.0
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
                began = time.monotonic()
                self._write(s.data)
                last_sent = time.monotonic()
                self.late.append(max(0.0, began - max(due, ready)))
                if not self.fast and ready > start + shift + s.at_s:
                    shift = ready - start - s.at_s  # the answers were late: so is the rest
                prev_at = s.at_s
                self.records.append(Record(self._ts(last_sent), Direction.TO_DEVICE, s.data))
                for _ in range(s.frames):
                    self.frame_sent_at.append(last_sent)
                    number = len(self.frame_sent_at)
                    self.sent_ns[number] = self._ts(began)
                    self.frame_late[number] = self.late[-1]
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


# --- the report ------------------------------------------------------------------------------


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))] if ordered else 0.0


@dataclass
class Outcome:
    """A finished replay: the verdicts and what else went wrong."""

    frames: int
    verdicts: list[Verdict]
    extra: list[str]  # answers the recording did not have (hex)
    aborted: str | None
    late: list[float]  # the pacing error of each run sent (s)
    problems: list[str] = field(default_factory=list)  # what the reader found wrong (warned)

    def count(self, result: str) -> int:
        return sum(1 for v in self.verdicts if v.result == result)

    @property
    def status(self) -> int:
        """0 no difference, 1 a difference, 3 no difference but answers not judged."""
        if self.count("differs") or self.extra or self.aborted:
            return 1
        return 3 if self.count("pacing") else 0

    def pacing(self) -> dict[str, float | int]:
        return {
            "runs": len(self.late),
            "p50_ms": round(_pct(self.late, 50) * 1000, 3),
            "p99_ms": round(_pct(self.late, 99) * 1000, 3),
            "max_ms": round(max(self.late, default=0.0) * 1000, 3),
        }


def report_json(args: argparse.Namespace, tol: Tolerances, out: Outcome) -> None:
    doc = {
        "file": [str(f) for f in args.files],
        "port": args.port,
        "fast": args.fast,
        "tolerances": {
            "time_ms": tol.time_s * 1000,
            "slide_percent": tol.slide * 100,
            "position_steps": tol.position,
        },
        "frames": out.frames,
        "exact": out.count("exact"),
        "tolerated": out.count("tolerated"),
        "differs": out.count("differs"),
        "pacing_not_judged": out.count("pacing"),
        "extra_answers": len(out.extra),
        "aborted": out.aborted,
        "pacing": out.pacing(),
        "verdicts": [v.__dict__ for v in out.verdicts if v.result != "exact"],
        "problems": out.problems,
        "ok": out.status == 0,
        "status": out.status,
    }
    print(json.dumps(doc, indent=1))


def report_text(args: argparse.Namespace, tol: Tolerances, out: Outcome) -> None:
    tags = {"differs": "DIFF", "tolerated": "near", "pacing": "PACE", "not compared": "----"}
    for v in out.verdicts:
        if v.result in tags and (v.result != "not compared" or args.verbose):
            print(f"{tags[v.result]:<5} {v.line()}")
        elif args.verbose:
            print(f"same  {v.line()}")
    for data in out.extra:
        print(f"DIFF  an answer more than the recording had: {data}")
    if out.aborted:
        print(f"DIFF  replay stopped: {out.aborted}")
    pace = out.pacing()
    due = "as soon as its answers came (--fast)" if args.fast else "at its recorded time"
    late = not args.fast and pace["max_ms"] > tol.time_s * 1000
    print(
        f"pacing: {pace['runs']} runs, each due {due}, sent p50 {pace['p50_ms']:.3f} ms, "
        f"p99 {pace['p99_ms']:.3f} ms, at most {pace['max_ms']:.3f} ms late"
        + (
            f": later than the {tol.time_s * 1000:.0f} ms of device timing the tolerances "
            "assume (a busy machine?)"
            if late
            else ""
        )
    )
    differ = out.count("differs") + len(out.extra) + (1 if out.aborted else 0)
    print(
        f"replay of {out.frames} frames against {args.port}"
        f"{' (--fast)' if args.fast else ''}: {out.count('exact')} answers byte-exact, "
        f"{out.count('tolerated')} within tolerance, {differ} differ"
        + (f", {out.count('pacing')} not judged (pacing)" if out.count("pacing") else "")
        + (": no difference" if out.status == 0 else "")
    )


# --- command line ----------------------------------------------------------------------------


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="play a recording's host side against a device and compare answers",
        description="Send the host -> device bytes of a trace file (motorctld --trace, "
        "motorctl tap) to a device as recorded, with the recorded pauses or --fast, and "
        "compare every answer with the recorded one: byte for byte, except those timing "
        "decides (a position read while moving or after a stop, whether a motion had "
        "ended, how long WaitMoved was held), which are judged from the motion they came "
        "from, each with how far it was and why that is allowed (docs/trace.md). Exit "
        "status 0 when every answer matches, 1 on a difference, 2 on an error, 3 when "
        "answers could not be judged because the replay kept the recording's timing less "
        "closely than their tolerance assumes.",
    )
    p.add_argument(
        "files",
        nargs="+",
        type=Path,
        metavar="FILE",
        help="the recording (motorctld --trace, motorctl tap; rotated parts in any order)",
    )
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
        type=number_in(0, 86_400_000, "ms"),
        default=TIME_TOLERANCE_S * 1000,
        metavar="MS",
        help="how much the device's own timing may differ between the recording and the "
        "replay: when a motion starts after its answer, how far its steps lag behind "
        "their plan, when its end is seen (default 50)",
    )
    p.add_argument(
        "--slide-tolerance",
        type=number_in(0, 1000, "%"),
        default=SLIDE_TOLERANCE * 100,
        metavar="PERCENT",
        help="how much further a motion may slide behind its plan in one run than in the "
        "other, as a share of its time so far: a device's late steps slide the rest of a "
        "move (docs/timing.md; default 5)",
    )
    p.add_argument(
        "--position-tolerance",
        type=whole_in(0, 1 << 24, "steps"),
        default=POSITION_TOLERANCE,
        metavar="STEPS",
        help="added to every position range that timing decides (default 2)",
    )
    p.add_argument(
        "--answer-timeout",
        type=number_in(0, 86_400, "s", lo_open=True),
        default=ANSWER_TIMEOUT_S,
        metavar="S",
        help="an answer later than recorded by this much ends the replay (default 5)",
    )
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="also list the answers that matched byte for byte",
    )
    p.add_argument("--json", action="store_true", help="the report as JSON")
    add_settings_options(p)


def _load(args: argparse.Namespace) -> tuple[Recording, list[Record], CaptureInfo]:
    """The recording, the records of the link it plays and their settings (the reader
    motorctl trace uses: the same files accepted, the same problems named); TraceFileError
    or ValueError naming the problem."""
    recording, link, info = one_link(
        args.files, args.interface, args.trace_checksum, args.frame_gap_ms
    )
    return recording, link.records, info


def _play(
    args: argparse.Namespace, records: list[Record], info: CaptureInfo, recorded: Conversation
) -> Player | str:
    """Play the recording's host side against the port; the player, or an error message."""
    sends = plan(records, info)
    rtts: list[float | None] = [
        None if f.answer is None or f.answer.rtt_ns is None else f.answer.rtt_ns / 1e9
        for f in recorded.frames
    ]
    expected = sum(1 for f in recorded.frames if f.answer is not None)
    problem = not_a_port(args.port)  # a file, a folder, a FIFO: refused unopened
    if problem is not None:
        return problem
    try:
        port = serial.Serial(args.port, args.baud, timeout=0, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as exc:
        return open_error(args.port, exc, args.baud)
    try:
        os.set_blocking(port.fileno(), False)
        player = Player(port.fileno(), args.fast, args.answer_timeout, rtts)
        player.aborted = player.play(sends, expected)
    finally:
        port.close()
    return player


def run(args: argparse.Namespace) -> int:
    if not args.port:
        print("error: no device port: pass --port PATH or set MOTORCTL_PORT", file=sys.stderr)
        return 2
    try:
        recording, records, info = _load(args)
    except (TraceFileError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    warn(recording.problems)
    if not any(r.direction is Direction.TO_DEVICE for r in records):
        named = ", ".join(map(str, args.files))
        print(
            f"error: nothing to replay: {named} hold{'s' if len(args.files) == 1 else ''} no "
            "host -> device bytes" + (" (see the warnings above)" if recording.problems else ""),
            file=sys.stderr,
        )
        return 2
    recorded = analyse(records, info)
    player = _play(args, records, info, recorded)
    if isinstance(player, str):
        print(f"error: {player}", file=sys.stderr)
        return 2
    replayed = analyse(player.records, info)
    tol = Tolerances(
        args.time_tolerance_ms / 1000.0, args.position_tolerance, args.slide_tolerance / 100.0
    )
    t0 = records[0].ts_ns
    verdicts = compare(
        recorded,
        replayed,
        windows(recorded),
        windows(replayed, player.sent_ns),
        tol,
        {} if args.fast else player.frame_late,
        t0,
    )
    extra = [r.data.hex(" ") for r in replayed.rows if r.kind == "extra_answer"]
    out = Outcome(
        len(recorded.frames), verdicts, extra, player.aborted, player.late, recording.problems
    )
    (report_json if args.json else report_text)(args, tol, out)
    return out.status
