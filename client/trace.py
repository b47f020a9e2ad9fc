"""``motorctl trace FILE...``: a recorded conversation, frame by frame (docs/trace.md).

:func:`analyse` turns byte runs (from the daemon's trace or the tap) into rows: each command
frame with its decoded command or its frame error, each answer decoded for the command it
answers (error codes by name) with its round-trip time, partial frames the gap rule dropped,
runs a writer left out. Inbound runs are cut into frames as the daemon cuts them
(:class:`motorctl.protocol.framing.Framer`, with the recording's ``frame_gap_ms``; the
silence between two recorded runs stands for the silence the daemon watched); answers are
paired with frames in order, as the protocol answers them (every complete frame gets exactly
one answer, in arrival order). The replay uses the same analysis.

Runs on the caller's thread; :func:`load` reads the files, the rest is computation.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from motorctl.protocol.capture import (
    Capture,
    CaptureError,
    CaptureInfo,
    Direction,
    Record,
    parse,
)
from motorctl.protocol.codec import (
    FRAME_LEN,
    RESPONSE_LEN,
    CodecOptions,
    Command,
    FrameError,
    GetAbsPos,
    GetPin,
    IsReady,
    Response,
    ResponseError,
    SaveWayPoint,
    decode_command,
    decode_response,
    describe,
)
from motorctl.protocol.framing import Framer

# --- reading files -------------------------------------------------------------------------


class TraceFileError(Exception):
    """A file that cannot be read as a trace; the message names it and says why."""


def load(paths: Sequence[Path]) -> Capture:
    """Read one or more trace files (rotated parts in any order: sorted by their first
    record's time) into one capture."""
    parts: list[tuple[int, Path, Capture]] = []
    for path in paths:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise TraceFileError(f"cannot read {path}: {exc.strerror or exc}") from None
        try:
            cap = parse(data)
        except CaptureError as exc:
            raise TraceFileError(f"{path}: {exc}") from None
        first = cap.records[0].ts_ns if cap.records else 0
        parts.append((first, path, cap))
    parts.sort(key=lambda p: p[0])
    out = Capture(info=None)
    for _, path, cap in parts:
        if out.info is None:
            out.info = cap.info
        elif cap.info is not None and cap.info != out.info:
            out.problems.append(f"{path}: recorded with other settings ({cap.info.comment()})")
        out.records += cap.records
        out.problems += [f"{path}: {p}" for p in cap.problems]
    return out


# --- analysis ------------------------------------------------------------------------------

COMMAND = "command"
BAD_FRAME = "bad_frame"
ANSWER = "answer"
BAD_ANSWER = "bad_answer"
EXTRA = "extra_answer"
GAP = "gap"
LOST = "lost"
PARTIAL = "partial"


@dataclass
class Row:
    """One line of the table: a frame, an answer or an event on the link."""

    t_ns: int
    direction: Direction
    kind: str
    data: bytes
    text: str
    frame: int | None = None  # the command frame's number (1 = first), for frames and answers
    command: Command | None = None
    response: Response | None = None
    error: str | None = None  # error code short name (answers) or frame error reason
    rtt_ns: int | None = None  # answers: from the last byte of the frame they answer


@dataclass
class Frame:
    """A complete command frame and what answered it."""

    number: int
    t_ns: int  # when its last byte was read
    data: bytes
    command: Command | None
    error: FrameError | None
    answer: Row | None = None


@dataclass
class Conversation:
    rows: list[Row] = field(default_factory=list)
    frames: list[Frame] = field(default_factory=list)
    partial_in: bytes = b""  # an incomplete frame at the end
    partial_out: bytes = b""  # an incomplete answer at the end
    lost_runs: int = 0

    @property
    def unanswered(self) -> list[Frame]:
        return [f for f in self.frames if f.answer is None]


def answer_text(cmd: Command | None, resp: Response) -> str:
    """What an answer says, for the command it answers: "ready", "pos=1200", "E3 ..."."""
    if not resp.ack:
        code = resp.error_code
        return (
            f"{code.short} {code.label}"
            if code is not None
            else f"error 0x{resp.payload[0]:02x} (unknown code)"
        )
    if isinstance(cmd, IsReady):
        return "ready" if resp.as_bool else "busy"
    if isinstance(cmd, GetAbsPos):
        return f"pos={resp.as_position}"
    if isinstance(cmd, GetPin):
        return "high" if resp.as_bool else "low"
    if isinstance(cmd, SaveWayPoint):
        return f"waypoint {resp.payload[0]}"
    return "ok" if resp.payload == bytes(3) else f"ok, payload {resp.payload.hex(' ')}"


def analyse(records: Sequence[Record], info: CaptureInfo) -> Conversation:
    """Frames, answers and events of a recording, in recorded order."""
    opts = info.codec_options()
    framer = Framer(info.frame_gap_ms / 1000.0)
    conv = Conversation()
    pending = bytearray()  # what the framer holds, to show a dropped partial frame
    out_buf = bytearray()
    last_in: int | None = None
    waiting: list[Frame] = []  # frames not answered yet, in order
    next_answer = 0
    for rec in records:
        if rec.dropped:
            conv.lost_runs += rec.dropped
            conv.rows.append(
                Row(
                    rec.ts_ns,
                    rec.direction,
                    LOST,
                    b"",
                    f"{rec.dropped} byte runs left out here (the trace writer "
                    "fell behind): frames and answers may pair wrongly after "
                    "this",
                )
            )
        if rec.direction is Direction.TO_DEVICE:
            if last_in is not None and framer.pending:
                silence = (rec.ts_ns - last_in) / 1e9
                if framer.idle(silence):
                    conv.rows.append(
                        Row(
                            rec.ts_ns,
                            Direction.TO_DEVICE,
                            GAP,
                            bytes(pending),
                            f"partial frame dropped: {len(pending)} of {FRAME_LEN} bytes, then "
                            f"{silence * 1000:.1f} ms of silence (> frame_gap_ms "
                            f"{info.frame_gap_ms:g}); no answer",
                        )
                    )
                    pending.clear()
            last_in = rec.ts_ns
            frames = framer.feed(rec.data)
            pending += rec.data
            del pending[: len(frames) * FRAME_LEN]
            for data in frames:
                frame = _frame(len(conv.frames) + 1, rec.ts_ns, data, opts)
                conv.frames.append(frame)
                waiting.append(frame)
                if frame.command is not None:
                    text = f"#{frame.number} {describe(frame.command)}"
                    conv.rows.append(
                        Row(
                            rec.ts_ns,
                            rec.direction,
                            COMMAND,
                            data,
                            text,
                            frame.number,
                            frame.command,
                        )
                    )
                else:
                    assert frame.error is not None
                    conv.rows.append(
                        Row(
                            rec.ts_ns,
                            rec.direction,
                            BAD_FRAME,
                            data,
                            f"#{frame.number} frame error ({frame.error.reason}):"
                            f" {frame.error}; E1 expected",
                            frame.number,
                            error=frame.error.reason,
                        )
                    )
        else:
            out_buf += rec.data
            while len(out_buf) >= RESPONSE_LEN:
                data = bytes(out_buf[:RESPONSE_LEN])
                del out_buf[:RESPONSE_LEN]
                target = waiting[next_answer] if next_answer < len(waiting) else None
                if target is not None:
                    next_answer += 1
                conv.rows.append(_answer(rec.ts_ns, data, target, opts))
    conv.partial_in = bytes(pending)
    conv.partial_out = bytes(out_buf)
    return conv


def _frame(number: int, t_ns: int, data: bytes, opts: CodecOptions) -> Frame:
    try:
        return Frame(number, t_ns, data, decode_command(data, opts), None)
    except FrameError as exc:
        return Frame(number, t_ns, data, None, exc)


def _answer(t_ns: int, data: bytes, frame: Frame | None, opts: CodecOptions) -> Row:
    if frame is None:
        return Row(
            t_ns,
            Direction.TO_HOST,
            EXTRA,
            data,
            "answer with no frame to answer (the device sent more answers than it "
            "got complete frames)",
        )
    rtt = t_ns - frame.t_ns
    try:
        resp = decode_response(data, opts)
    except ResponseError as exc:
        row = Row(
            t_ns,
            Direction.TO_HOST,
            BAD_ANSWER,
            data,
            f"#{frame.number} bad answer: {exc}",
            frame.number,
            frame.command,
            rtt_ns=rtt,
        )
    else:
        code = resp.error_code
        row = Row(
            t_ns,
            Direction.TO_HOST,
            ANSWER,
            data,
            f"#{frame.number} {answer_text(frame.command, resp)}",
            frame.number,
            frame.command,
            resp,
            code.short if code is not None else None,
            rtt,
        )
    frame.answer = row
    return row


# --- output --------------------------------------------------------------------------------


def _pct(values: list[int], q: float) -> int:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))]


def summary(conv: Conversation) -> dict[str, Any]:
    """Counts, errors by name and round-trip times per command."""
    errors: dict[str, int] = {}
    rtts: dict[str, list[int]] = {}
    for row in conv.rows:
        if row.kind == ANSWER and row.response is not None and not row.response.ack:
            code = row.response.error_code
            name = f"{code.short} {code.label}" if code else f"0x{row.response.payload[0]:02x}"
            errors[name] = errors.get(name, 0) + 1
        if row.kind == ANSWER and row.rtt_ns is not None:
            name = type(row.command).__name__ if row.command is not None else "bad frame"
            rtts.setdefault(name, []).append(row.rtt_ns)
    return {
        "frames": len(conv.frames),
        "commands": sum(1 for f in conv.frames if f.command is not None),
        "frame_errors": sum(1 for f in conv.frames if f.command is None),
        "answers": sum(1 for r in conv.rows if r.kind in (ANSWER, BAD_ANSWER)),
        "bad_answers": sum(1 for r in conv.rows if r.kind == BAD_ANSWER),
        "extra_answers": sum(1 for r in conv.rows if r.kind == EXTRA),
        "unanswered": [f.number for f in conv.unanswered],
        "gap_discards": sum(1 for r in conv.rows if r.kind == GAP),
        "lost_runs": conv.lost_runs,
        "partial_frame_at_end": conv.partial_in.hex(" "),
        "partial_answer_at_end": conv.partial_out.hex(" "),
        "errors": errors,
        "rtt_us": {
            name: {
                "n": len(v),
                "p50": round(_pct(v, 50) / 1e3, 1),
                "p99": round(_pct(v, 99) / 1e3, 1),
                "max": round(max(v) / 1e3, 1),
            }
            for name, v in sorted(rtts.items())
        },
    }


def row_json(row: Row, t0: int) -> dict[str, Any]:
    return {
        "t": round((row.t_ns - t0) / 1e9, 9),
        "ts_ns": row.t_ns,
        "dir": "to_device" if row.direction is Direction.TO_DEVICE else "to_host",
        "kind": row.kind,
        "bytes": row.data.hex(" "),
        "text": row.text,
        "frame": row.frame,
        "error": row.error,
        "rtt_us": None if row.rtt_ns is None else round(row.rtt_ns / 1e3, 1),
    }


def info_json(info: CaptureInfo) -> dict[str, Any]:
    return {
        "role": info.role,
        "checksum": info.checksum,
        "crc_covers_ack": info.crc_covers_ack,
        "strict_padding": info.strict_padding,
        "frame_gap_ms": info.frame_gap_ms,
        "port": info.port,
        "application": info.application,
    }


def print_table(conv: Conversation, info: CaptureInfo, problems: list[str], t0: int) -> None:
    print(
        f"# {info.role} trace of {info.port or 'an unnamed port'} ({info.application}); "
        f"checksum {info.checksum}, frame_gap_ms {info.frame_gap_ms:g}"
    )
    print(f"{'time s':>12}  dir  {'bytes':<29}  {'rtt':>10}  decoded")
    for row in conv.rows:
        rtt = "" if row.rtt_ns is None else _duration(row.rtt_ns)
        arrow = row.direction.arrow if row.kind != LOST else "!!"
        print(
            f"{(row.t_ns - t0) / 1e9:12.6f}  {arrow:<3}  {row.data.hex(' '):<29}  "
            f"{rtt:>10}  {row.text}"
        )
    s = summary(conv)
    print(
        f"# {s['frames']} frames ({s['frame_errors']} frame errors), {s['answers']} "
        f"answers, {s['gap_discards']} partial frames dropped by the gap rule, "
        f"{len(s['unanswered'])} unanswered, {s['extra_answers']} extra answers"
    )
    if s["errors"]:
        print("# error answers: " + ", ".join(f"{k}: {v}" for k, v in s["errors"].items()))
    for name, r in s["rtt_us"].items():
        print(f"# rtt {name}: n {r['n']}  p50 {r['p50']} us  p99 {r['p99']} us  max {r['max']} us")
    if conv.partial_in:
        print(f"# at the end: an incomplete frame ({conv.partial_in.hex(' ')})")
    if conv.partial_out:
        print(f"# at the end: an incomplete answer ({conv.partial_out.hex(' ')})")
    for p in problems:
        print(f"# note: {p}")


def _duration(ns: int) -> str:
    if ns >= 10_000_000:
        return f"{ns / 1e9:.3f} s"
    return f"{ns / 1e3:.0f} us"


def settings(
    cap: Capture, checksum: str | None, frame_gap_ms: float | None, crc_covers_ack: bool
) -> CaptureInfo:
    """The recording's settings, with what the command line overrides; ValueError for a bad
    checksum name."""
    info = cap.info or CaptureInfo(role="unknown")
    if checksum is not None:
        info = replace(info, checksum=checksum)
    if frame_gap_ms is not None:
        info = replace(info, frame_gap_ms=frame_gap_ms)
    if crc_covers_ack:
        info = replace(info, crc_covers_ack=True)
    info.codec_options()
    return info


def add_settings_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--frame-gap-ms",
        type=float,
        metavar="MS",
        help="frame gap to cut frames with (default: the recording's)",
    )
    p.add_argument(
        "--trace-checksum",
        metavar="NAME",
        dest="trace_checksum",
        help="checksum to decode with (default: the recording's)",
    )


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "trace",
        help="print a trace file (motorctld --trace, motorctl tap) frame by frame",
        description="Print a recorded conversation: time, direction, raw bytes, the decoded "
        "command or answer (error codes by name), frame errors, partial frames the gap rule "
        "dropped, and each command's round-trip time. docs/trace.md.",
    )
    p.add_argument(
        "files",
        nargs="+",
        type=Path,
        metavar="FILE",
        help="trace files (rotated parts FILE.1 FILE ... in any order)",
    )
    p.add_argument("--json", action="store_true", help="one JSON document for tools")
    add_settings_options(p)


def run(args: argparse.Namespace) -> int:
    try:
        cap = load(args.files)
        info = settings(cap, args.trace_checksum, args.frame_gap_ms, False)
    except TraceFileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    conv = analyse(cap.records, info)
    t0 = cap.records[0].ts_ns if cap.records else 0
    problems = list(cap.problems)
    if cap.info is None:
        problems.append("no motorctl header: decoded with the default settings")
    if args.json:
        doc = {
            "info": info_json(info),
            "t0_ns": t0,
            "rows": [row_json(r, t0) for r in conv.rows],
            "summary": summary(conv),
            "problems": problems,
        }
        json.dump(doc, sys.stdout, indent=1)
        print()
    else:
        print_table(conv, info, problems, t0)
    return 0
