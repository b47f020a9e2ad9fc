"""The trace format (protocol/capture.py), the daemon's recorder (rotation, bounds) and the
reader's and the replay's analysis, on made-up byte runs: no process, no clock."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from motorctl.client.replay import Tolerances, compare, plan
from motorctl.client.trace import BAD_FRAME, EXTRA, GAP, LOST, analyse, load
from motorctl.daemon.link.recorder import TraceRecorder, rotated
from motorctl.protocol.capture import (
    LINKTYPE_USER0,
    CaptureError,
    CaptureInfo,
    Direction,
    Record,
    encode,
    header,
    parse,
)
from motorctl.protocol.codec import (
    CodecOptions,
    ErrorCode,
    GetAbsPos,
    IsReady,
    MoveTo,
    Response,
    SetPin,
    encode_command,
    encode_response,
)

OPTS = CodecOptions()
IN, OUT = Direction.TO_DEVICE, Direction.TO_HOST
INFO = CaptureInfo(role="daemon", frame_gap_ms=10.0, port="/dev/test")
MS = 1_000_000


def cmd(c: object) -> bytes:
    return encode_command(c, OPTS)  # type: ignore[arg-type]


def ans(r: Response) -> bytes:
    return encode_response(r, OPTS)


def test_round_trip_keeps_every_run_its_time_direction_and_drop_count() -> None:
    records = [
        Record(1_700_000_000_123_456_789, IN, b"\x03" + bytes(8) + b"\x8b"),
        Record(1_700_000_000_123_556_789, OUT, b"\x01\x01\x00\x00\x6b"),
        Record(1_700_000_001_000_000_000, IN, b"\x07", dropped=3),
        Record(1_700_000_001_000_000_001, OUT, b""),
    ]
    cap = parse(encode(INFO, records))
    assert cap.info == INFO
    assert cap.records == records
    assert cap.problems == []


def test_a_file_cut_mid_block_gives_its_complete_blocks_and_says_so() -> None:
    records = [Record(i * MS, IN, bytes([i]) * 10) for i in range(5)]
    data = encode(INFO, records)
    cap = parse(data[:-7])
    assert cap.records == records[:4]
    assert cap.truncated_bytes > 0 and "ends inside a block" in cap.problems[0]


def test_header_is_standard_pcapng_with_the_user0_link_type() -> None:
    data = header(INFO)
    kind, total, magic, major, minor = struct.unpack_from("<IIIHH", data)
    assert (kind, magic, major, minor) == (0x0A0D0D0A, 0x1A2B3C4D, 1, 0)
    idb = data[total:]
    assert struct.unpack_from("<IIH", idb)[0] == 1
    assert struct.unpack_from("<H", idb, 8)[0] == LINKTYPE_USER0 == 147


def test_not_a_trace_and_a_later_version_are_refused_by_name() -> None:
    with pytest.raises(CaptureError, match="not a pcapng"):
        parse(b"hello world, not a capture")
    newer = header(INFO).replace(b"motorctl-trace/1", b"motorctl-trace/9")
    with pytest.raises(CaptureError, match="version 9"):
        parse(newer)


def test_concatenated_files_read_as_one() -> None:
    a = encode(INFO, [Record(1, IN, b"a")])
    b = encode(INFO, [Record(2, OUT, b"b")])
    assert [r.data for r in parse(a + b).records] == [b"a", b"b"]


def test_recorder_rotates_within_its_bounds_and_keeps_the_newest(tmp_path: Path) -> None:
    path = tmp_path / "t.pcapng"
    rec = TraceRecorder(
        path, INFO, max_bytes=2000, files=3, clock_origin=0.0, wall_origin_ns=0, flush_s=3600
    )
    rec.open()
    for i in range(200):
        rec.received(bytes([i % 256]) * 10, i / 1000)
        rec.sent(bytes([i % 256]) * 5, i / 1000 + 0.0001)
        if i % 20 == 19:
            rec._flush()  # what the writer thread does every flush_s
    rec.close()
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == ["t.pcapng", "t.pcapng.1", "t.pcapng.2"]
    assert all(f.stat().st_size <= 2000 for f in files)
    assert rec.rotations > 2 and rec.dropped_runs == 0
    cap = load([rotated(path, 2), path, rotated(path, 1)])  # any order
    times = [r.ts_ns for r in cap.records]
    assert times == sorted(times) and cap.problems == []
    # the newest runs are all there, up to the last one, without a hole
    assert times[-1] == round(0.199 * 1e9 + 0.0001 * 1e9)
    expected = sorted(
        [round(i / 1000 * 1e9) for i in range(200)]
        + [round((i / 1000 + 0.0001) * 1e9) for i in range(200)]
    )
    assert times == expected[-len(times) :]


def test_recorder_memory_is_bounded_and_the_loss_is_written_down(tmp_path: Path) -> None:
    path = tmp_path / "t.pcapng"
    rec = TraceRecorder(
        path,
        INFO,
        max_bytes=1 << 20,
        files=1,
        clock_origin=0.0,
        wall_origin_ns=0,
        flush_s=3600,
        buffer_limit=500,
    )
    rec.open()
    for i in range(50):  # the writer never runs: the buffer fills
        rec.received(bytes(10), i / 1000)
    rec._flush()
    rec.received(b"\x03" * 10, 1.0)
    rec.close()
    cap = parse(path.read_bytes())
    assert rec.dropped_runs == 50 - len(cap.records) + 1 > 0
    assert cap.records[-1].dropped == rec.dropped_runs
    conv = analyse(cap.records, INFO)
    assert any(r.kind == LOST for r in conv.rows)


def conversation() -> list[Record]:
    """IsReady; a MoveTo; a split frame with a gap; a bad checksum; reads while moving."""
    return [
        Record(0, IN, cmd(IsReady(0))),
        Record(1 * MS, OUT, ans(Response.boolean(True))),
        Record(2 * MS, IN, cmd(MoveTo(0, True, 1000, 0, 0, 0))),
        Record(3 * MS, OUT, ans(Response.ok())),
        Record(4 * MS, IN, b"\x06\x00\x00"),  # a partial frame ...
        Record(30 * MS, IN, cmd(GetAbsPos(0))),  # ... dropped after 26 ms of silence
        Record(31 * MS, OUT, ans(Response.position(100))),
        Record(132 * MS, IN, cmd(GetAbsPos(0))[:4]),  # one frame in two runs
        Record(133 * MS, IN, cmd(GetAbsPos(0))[4:]),
        Record(134 * MS, OUT, ans(Response.position(200))),
        Record(140 * MS, IN, cmd(SetPin(5, True))[:9] + b"\x00"),  # bad checksum
        Record(141 * MS, OUT, ans(Response.error(ErrorCode.INVALID_COMMAND))),
        Record(150 * MS, OUT, ans(Response.ok())),  # an answer nobody asked for
    ]


def test_analysis_frames_as_the_daemon_does_and_pairs_answers_in_order() -> None:
    conv = analyse(conversation(), INFO)
    kinds = [r.kind for r in conv.rows]
    assert kinds.count(GAP) == 1 and kinds.count(BAD_FRAME) == 1 and kinds.count(EXTRA) == 1
    assert len(conv.frames) == 5
    assert [f.answer.text if f.answer else None for f in conv.frames] == [
        "#1 ready",
        "#2 ok",
        "#3 pos=100",
        "#4 pos=200",
        "#5 E1 Invalid Command",
    ]
    assert conv.frames[3].answer is not None and conv.frames[3].answer.rtt_ns == 1 * MS
    assert conv.frames[3].t_ns == 133 * MS  # its last byte's run


def test_no_gap_when_silence_is_exactly_the_frame_gap() -> None:
    records = [Record(0, IN, b"\x03\x00"), Record(10 * MS, IN, cmd(IsReady(0))[2:])]
    conv = analyse(records, INFO)
    assert [r.kind for r in conv.rows] == ["command"]


def test_plan_waits_for_answers_and_keeps_framing_pauses() -> None:
    sends = plan(conversation(), INFO)
    assert [s.need for s in sends] == [0, 1, 2, 2, 3, 3, 4]
    assert sends[3].at_s == pytest.approx(0.030)
    assert [s.framing for s in sends] == [False, False, False, True, False, True, False]


def _replayed(pos3: int, pos4: int, pin_answer: Response) -> list[Record]:
    recs = conversation()
    out = []
    for r in recs:
        if r.data == ans(Response.position(100)):
            r = Record(r.ts_ns, OUT, ans(Response.position(pos3)))
        elif r.data == ans(Response.position(200)):
            r = Record(r.ts_ns, OUT, ans(Response.position(pos4)))
        elif r.data == ans(Response.error(ErrorCode.INVALID_COMMAND)):
            r = Record(r.ts_ns, OUT, ans(pin_answer))
        out.append(r)
    return out[:-1]


def test_compare_tolerates_moving_positions_and_names_a_changed_answer() -> None:
    rec = analyse(conversation()[:-1], INFO)
    tol = Tolerances(time_s=0.05, position=2)
    # speed around the reads: 100 steps in 103 ms, ~970 step/s: tolerance ~ 2 + 48
    same = compare(
        rec, analyse(_replayed(130, 160, Response.error(ErrorCode.INVALID_COMMAND)), INFO), tol, 0
    )
    assert [v.result for v in same] == ["exact", "exact", "tolerated", "tolerated", "exact"]
    off = compare(
        rec, analyse(_replayed(300, 200, Response.error(ErrorCode.INVALID_ADDRESS)), INFO), tol, 0
    )
    assert [v.result for v in off] == ["exact", "exact", "differs", "exact", "differs"]
    assert "E2 Invalid Address" in off[4].replayed and "E1 Invalid Command" in off[4].recorded
    assert off[4].frame == 5


def test_compare_fast_accepts_any_position_the_motion_covers() -> None:
    rec = analyse(conversation()[:-1], INFO)
    tol = Tolerances(time_s=0.05, position=2, fast=True)
    inside = compare(
        rec, analyse(_replayed(1000, 0, Response.error(ErrorCode.INVALID_COMMAND)), INFO), tol, 0
    )
    assert [v.result for v in inside][2:4] == ["tolerated", "tolerated"]
    beyond = compare(
        rec, analyse(_replayed(1003, 0, Response.error(ErrorCode.INVALID_COMMAND)), INFO), tol, 0
    )
    assert beyond[2].result == "differs"
