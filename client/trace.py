"""``motorctl trace FILE...``: a recorded conversation, frame by frame (docs/trace.md): the
analysis (:mod:`motorctl.client.conversation`) shown as a table, or as ``--json``'s rows
with the typed fields docs/trace.md's schema lists; the settings a recording is decoded
with, which the replay shares.

Runs on the caller's thread; :func:`motorctl.client.recording.load` reads the files (and is
the replay's reader too), the rest is computation.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from motorctl.client.arguments import number_in
from motorctl.client.conversation import (
    ANSWER,
    BAD_ANSWER,
    BAD_FRAME,
    COMMAND,
    EXTRA,
    GAP,
    LOST,
    Conversation,
    Row,
    analyse,
)
from motorctl.client.recording import Link, Recording

# the reader, re-exported: motorctl.client.trace.load was its home before client/recording.py
from motorctl.client.recording import TraceFileError as TraceFileError
from motorctl.client.recording import load as load
from motorctl.protocol.capture.format import CaptureInfo, Direction
from motorctl.protocol.codec import COMMANDS, Command, Response, decode_answer


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
            name = row.command.spec.name if row.command is not None else "bad frame"
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


def _keys() -> tuple[str, ...]:
    """The command table's fields as ``--json`` names them: each command's parameters and
    each answer's value, in the table's order, each once."""
    keys: dict[str, None] = {}
    for cls in COMMANDS:
        value = cls.spec.answer.value
        for p in (*cls.spec.params, *([value] if value is not None else [])):
            keys[p.field] = None
    return tuple(keys)


#: the typed keys of every row of ``motorctl trace --json`` (docs/trace.md, "JSON"), null
#: where they do not apply: the command's name and code, the table's fields, R0, the error
FIELDS = ("command", "code", *_keys(), "ack", "error_code", "error_name")


def direction_word(cmd: Command) -> str | None:
    """A command's direction byte as the CLI names it: up/down, forward/reverse (DcMove)."""
    p = cmd.spec.param("direction")
    return None if p is None else p.text(getattr(cmd, "direction"))  # noqa: B009


def command_fields(cmd: Command | None) -> dict[str, Any]:
    """A command's fields, typed as the table shows them: ``command`` (its name), ``code``
    (B0), the parameters (``direction`` as a word, SetPin's level as ``value`` 1/0); None
    where absent."""
    out: dict[str, Any] = dict.fromkeys(FIELDS)
    if cmd is None:
        return out
    out["command"] = cmd.spec.name
    out["code"] = cmd.code
    for p in cmd.spec.params:
        out[p.field] = p.json(getattr(cmd, p.name))
    return out


def answer_fields(cmd: Command | None, resp: Response | None) -> dict[str, Any]:
    """An answer's fields, typed, for the command it answers: ``command``, ``code``,
    ``motor``, ``pin`` of that command; ``ack``; the value the table says it carries
    (``ready`` for IsReady, ``position`` for GetAbsPos, ``value`` 1/0 for GetPin,
    ``waypoint`` for SaveWayPoint); ``error_code`` (0xE3 = 227) and ``error_name`` ("Motor
    not ready") of an error answer."""
    out: dict[str, Any] = dict.fromkeys(FIELDS)
    if cmd is not None:
        out["command"] = cmd.spec.name
        out["code"] = cmd.code
        out["motor"] = getattr(cmd, "motor", None)
        out["pin"] = getattr(cmd, "pin", None)
    if resp is None:
        return out
    reading = decode_answer(cmd, resp)
    out["ack"] = reading.ack
    if reading.error_byte is not None:
        out["error_code"] = reading.error_byte
        out["error_name"] = reading.error.label if reading.error else "unknown error code"
    elif reading.param is not None and reading.value is not None:
        out[reading.param.field] = reading.param.json(reading.value)
    return out


def row_json(row: Row, t0: int, file: str | None = None) -> dict[str, Any]:
    """One row for ``--json`` (docs/trace.md, "JSON"): where and when, the bytes and text,
    and the typed fields of :data:`FIELDS`."""
    doc: dict[str, Any] = {
        "t": round((row.t_ns - t0) / 1e9, 9),
        "ts_ns": row.t_ns,
        "interface": row.interface,
        "packet": row.packet,
    }
    if file is not None:
        doc["file"] = file
    doc.update(
        {
            "dir": "to_device" if row.direction is Direction.TO_DEVICE else "to_host",
            "kind": row.kind,
            "bytes": row.data.hex(" "),
            "text": row.text,
            "frame": row.frame,
            "error": row.error,
            "rtt_us": None if row.rtt_ns is None else round(row.rtt_ns / 1e3, 1),
        }
    )
    if row.kind == COMMAND:
        doc.update(command_fields(row.command))
    elif row.kind in (ANSWER, BAD_ANSWER):
        doc.update(answer_fields(row.command, row.response))
    elif row.kind == BAD_FRAME:
        fields = dict.fromkeys(FIELDS)
        fields["code"] = row.data[0] if row.data else None
        doc.update(fields)
    else:
        doc.update(dict.fromkeys(FIELDS))
    return doc


def info_json(info: CaptureInfo) -> dict[str, Any]:
    return {
        "role": info.role,
        "checksum": info.checksum,
        "crc_covers_ack": info.crc_covers_ack,
        "strict_padding": info.strict_padding,
        "frame_gap_ms": info.frame_gap_ms,
        "port": info.port,
        "application": info.application,
        "session": info.session or None,
        "part": info.part or None,
    }


def print_table(
    conv: Conversation, info: CaptureInfo, problems: list[str], t0: int, title: str = ""
) -> None:
    print(
        f"# {title}{info.role} trace of {info.port or 'an unnamed port'} ({info.application}); "
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
    info: CaptureInfo | None, checksum: str | None, frame_gap_ms: float | None, crc_covers_ack: bool
) -> CaptureInfo:
    """A link's settings (None: no motorctl header: the defaults), with what the command
    line overrides; ValueError for a bad checksum name."""
    info = info or CaptureInfo(role="unknown")
    if checksum is not None:
        info = replace(info, checksum=checksum)
    if frame_gap_ms is not None:
        info = replace(info, frame_gap_ms=frame_gap_ms)
    if crc_covers_ack:
        info = replace(info, crc_covers_ack=True)
    info.codec_options()
    return info


def one_link(
    paths: Sequence[Path], interface: int | None, checksum: str | None, frame_gap_ms: float | None
) -> tuple[Recording, Link, CaptureInfo]:
    """The one link a replay plays: TraceFileError when the files hold several and
    ``interface`` picks none; ValueError for a bad checksum name."""
    recording = load(paths, interface)
    if len(recording.links) > 1:
        raise TraceFileError(
            f"{', '.join(map(str, paths))} hold{'s' if len(paths) == 1 else ''} "
            f"{len(recording.links)} motorctl links (interfaces "
            f"{recording.describe_interfaces()}): pass --interface N to pick one"
        )
    link = recording.links[0]
    return recording, link, settings(link.info, checksum, frame_gap_ms, False)


def add_settings_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--frame-gap-ms",
        type=number_in(0, 10_000, "ms"),
        metavar="MS",
        help="frame gap to cut frames with (default: the recording's)",
    )
    p.add_argument(
        "--trace-checksum",
        metavar="NAME",
        dest="trace_checksum",
        help="checksum to decode with (default: the recording's)",
    )
    p.add_argument(
        "--interface",
        type=int,
        metavar="N",
        help="read only interface N of a file holding several (a mergecap of the tap's "
        "recording and the daemon's trace); the reader lists them",
    )


def warn(problems: Sequence[str]) -> None:
    """Each problem reading the files, on stderr."""
    for p in problems:
        print(f"warning: {p}", file=sys.stderr)


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "trace",
        help="print a trace file (motorctld --trace, motorctl tap) frame by frame",
        description="Print a recorded conversation: time, direction, raw bytes, the decoded "
        "command or answer (error codes by name), frame errors, partial frames the gap rule "
        "dropped, and each command's round-trip time. A file of several interfaces (mergecap) "
        "is decoded link by link (--interface N: one). Problems reading the files (damage, a "
        "missing rotated part, a pcap file) are named on stderr. docs/trace.md.",
    )
    p.add_argument(
        "files",
        nargs="+",
        type=Path,
        metavar="FILE",
        help="trace files (rotated parts FILE.1 FILE ... in any order)",
    )
    p.add_argument(
        "--json", action="store_true", help="one JSON document for tools (docs/trace.md)"
    )
    add_settings_options(p)


def run(args: argparse.Namespace) -> int:
    try:
        recording = load(args.files, args.interface)
        infos = [
            settings(link.info, args.trace_checksum, args.frame_gap_ms, False)
            for link in recording.links
        ]
    except (TraceFileError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    problems = _problems(recording, len(args.files))
    warn(problems)
    convs = [analyse(link.records, info) for link, info in zip(recording.links, infos, strict=True)]
    starts = [link.records[0].ts_ns for link in recording.links if link.records]
    t0 = min(starts) if starts else 0
    if args.json:
        json.dump(
            _json_doc(args.files, recording, infos, convs, problems, t0), sys.stdout, indent=1
        )
        print()
        return 0
    for link, info, conv in zip(recording.links, infos, convs, strict=True):
        title = f"interface {link.interface}: " if len(recording.links) > 1 else ""
        print_table(conv, info, problems if link is recording.links[-1] else [], t0, title)
    return 0


def _problems(recording: Recording, files: int) -> list[str]:
    """What the reader of ``files`` files found, and what was decoded how: said first."""
    problems = list(recording.problems)
    if len(recording.interfaces) > 1:
        problems.insert(
            0,
            f"the file{'s hold' if files > 1 else ' holds'} interfaces "
            f"{recording.describe_interfaces()}: "
            + (
                "each decoded as its own link (--interface N reads one)"
                if len(recording.links) > 1
                else f"interface {recording.links[0].interface} read"
            ),
        )
    for link in recording.links:
        if link.info is None:
            problems.append(
                f"interface {link.interface}: no motorctl header: decoded with the default settings"
            )
    return problems


def _json_doc(
    files: list[Path],
    recording: Recording,
    infos: list[CaptureInfo],
    convs: list[Conversation],
    problems: list[str],
    t0: int,
) -> dict[str, Any]:
    """``motorctl trace --json``'s document (docs/trace.md)."""
    several = len(files) > 1
    rows: list[dict[str, Any]] = []
    for link, conv in zip(recording.links, convs, strict=True):
        rows += [row_json(r, t0, link.file_of(r.run) if several else None) for r in conv.rows]
    rows.sort(key=lambda r: r["ts_ns"])
    links = [
        {
            "interface": link.interface,
            "name": link.name,
            "info": info_json(info),
            "runs": len(link.records),
            "sessions": link.sessions,
            "summary": summary(conv),
        }
        for link, info, conv in zip(recording.links, infos, convs, strict=True)
    ]
    doc: dict[str, Any] = {
        "files": [str(f) for f in files],
        "formats": recording.formats,
        "interfaces": [
            {
                "interface": i.number,
                "link_type": i.link_type,
                "name": i.name,
                "role": i.info.role if i.info is not None else None,
                "decoded": any(link.interface == i.number for link in recording.links),
            }
            for i in recording.interfaces
        ],
        "links": links,
        "t0_ns": t0,
    }
    if len(links) == 1:
        doc["info"] = links[0]["info"]
        doc["summary"] = links[0]["summary"]
    doc["rows"] = rows
    doc["problems"] = problems
    return doc
