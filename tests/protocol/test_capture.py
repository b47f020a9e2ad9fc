"""The trace format (protocol/capture.py), the daemon's recorder (rotation, bounds) and the
reader's and the replay's analysis, on made-up byte runs: no process, no clock. How the
replay judges answers: tests/client/test_judge.py."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from motorctl.client.recording import TraceFileError
from motorctl.client.replay import plan
from motorctl.client.trace import (
    BAD_FRAME,
    EXTRA,
    FIELDS,
    GAP,
    LOST,
    analyse,
    load,
    one_link,
    row_json,
)
from motorctl.daemon.trace import TraceRecorder, rotated
from motorctl.protocol.capture import (
    LINKTYPE_USER0,
    CaptureError,
    CaptureInfo,
    Direction,
    Record,
    RecordEncoder,
    direction_of,
    encode,
    header,
    parse,
)
from motorctl.protocol.codec import (
    CodecOptions,
    DcMove,
    ErrorCode,
    GetAbsPos,
    GetPin,
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
    assert times == sorted(times)
    # the parts are numbered: the first ones were rotated away, and the reader says so
    (note,) = cap.problems
    assert f"the start of session {rec.session}" in note and "is missing" in note
    assert cap.links[0].sessions == {rec.session: [rec.part - 2, rec.part - 1, rec.part]}
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


# --- rotated parts, merged files, pcap, damage --------------------------------------------------


def _rotating(tmp_path: Path, files: int) -> tuple[TraceRecorder, Path]:
    path = tmp_path / "t.pcapng"
    rec = TraceRecorder(
        path, INFO, max_bytes=600, files=files, clock_origin=0.0, wall_origin_ns=0, flush_s=3600
    )
    rec.open()
    for i in range(40):
        rec.received(cmd(IsReady(0)), i / 100)
        rec.sent(ans(Response.boolean(True)), i / 100 + 0.001)
        rec._flush()
    rec.close()
    return rec, path


def test_a_missing_part_is_named_and_a_complete_set_reads_clean(tmp_path: Path) -> None:
    rec, path = _rotating(tmp_path, files=100)
    parts = sorted(tmp_path.iterdir())
    assert rec.part == len(parts) > 3
    whole = load(parts)
    assert whole.problems == [] and len(whole.records) == 80
    assert analyse(whole.records, INFO).unanswered == []
    rotated(path, 1).unlink()  # the part before the newest: a hole
    holed = load(sorted(tmp_path.iterdir()))
    (note,) = holed.problems
    assert f"session {rec.session}" in note and f"lacks part {rec.part - 1}" in note
    newest = load([path])  # one part alone: its session's start is missing
    assert any("start of session" in p for p in newest.problems)


def test_a_part_given_twice_is_left_out_and_files_that_overlap_are_refused(
    tmp_path: Path,
) -> None:
    _, path = _rotating(tmp_path, files=100)
    parts = sorted(tmp_path.iterdir())
    copy = tmp_path / "copy.pcapng"
    copy.write_bytes(path.read_bytes())
    twice = load([path, copy])
    assert any("was given already" in p for p in twice.problems)
    other = tmp_path / "other.pcapng"  # a second recording of the same time: not a part
    other.write_bytes(
        encode(
            CaptureInfo(session="bbbb", part=1),
            [Record(5 * MS, IN, cmd(IsReady(0))), Record(390 * MS, OUT, ans(Response.ok()))],
        )
    )
    with pytest.raises(TraceFileError, match="overlap in time"):
        load([*parts, other])


def merged(a: tuple[CaptureInfo, list[Record]], b: tuple[CaptureInfo, list[Record]]) -> bytes:
    """What mergecap makes of two recordings: one section, two interfaces, the packets in
    time order, each naming its interface."""
    head_b = header(b[0])
    shb_len = struct.unpack_from("<I", head_b, 4)[0]
    enc = RecordEncoder()
    packets = sorted([(r, 0) for r in a[1]] + [(r, 1) for r in b[1]], key=lambda p: p[0].ts_ns)
    out = bytearray(header(a[0]) + head_b[shb_len:])
    for r, iface in packets:
        block = bytearray(enc.encode(r.ts_ns, r.direction, r.data))
        struct.pack_into("<I", block, 8, iface)
        out += block
    return bytes(out)


def test_a_merged_file_decodes_each_interface_as_its_own_link(tmp_path: Path) -> None:
    device = CaptureInfo(role="daemon", port="/dev/ttyAMA0", session="d", part=1)
    tap = CaptureInfo(role="tap", port="host A <-> device B", frame_gap_ms=20, session="t", part=1)
    talk = conversation()[:4]
    later = [Record(r.ts_ns + 50_000, r.direction, r.data) for r in talk]  # the tap, a bit later
    path = tmp_path / "merged.pcapng"
    path.write_bytes(merged((device, talk), (tap, later)))
    both = load([path])
    assert [link.interface for link in both.links] == [0, 1]
    assert [link.info.role for link in both.links if link.info] == ["daemon", "tap"]
    assert both.links[1].info is not None and both.links[1].info.frame_gap_ms == 20
    for link in both.links:  # each link pairs its own answers: nothing twice, nothing extra
        conv = analyse(link.records, link.info or INFO)
        assert len(conv.frames) == 2 and conv.unanswered == []
        assert not [r for r in conv.rows if r.kind == EXTRA]
    assert (
        both.describe_interfaces()
    ) == "0: /dev/ttyAMA0 (daemon, 4 runs), 1: host A <-> device B (tap, 4 runs)"
    one = load([path], interface=1)
    assert [link.interface for link in one.links] == [1]
    assert [(r.ts_ns, r.data, r.interface) for r in one.records] == [
        (r.ts_ns, r.data, 1) for r in later
    ]
    with pytest.raises(TraceFileError, match="pass --interface N"):
        one_link([path], None, None, None)  # the replay's reader: one link or none
    with pytest.raises(TraceFileError, match="no motorctl interface 7"):
        load([path], interface=7)


def pcap(records: list[Record], linktype: int = LINKTYPE_USER0) -> bytes:
    """The classic pcap file editcap -F pcap makes: no directions."""
    out = struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 0xFFFF, linktype)
    for r in records:
        out += struct.pack("<IIII", r.ts_ns // 10**9, r.ts_ns % 10**9, len(r.data), len(r.data))
        out += r.data
    return out


def test_a_pcap_file_says_so_and_reads_the_directions_its_bytes_tell(tmp_path: Path) -> None:
    talk = conversation()
    cap = parse(pcap(talk))
    assert cap.format == "pcap"
    told = [r for r in talk if direction_of(r.data, OPTS) is not None]
    assert [(r.ts_ns, r.direction, r.data) for r in cap.records] == [
        (r.ts_ns, r.direction, r.data) for r in told
    ]
    untold = len(talk) - len(told)  # the partial frames and the frame with a bad checksum
    assert untold == 4
    offset = 24 + sum(16 + len(r.data) for r in talk[:4])  # the first partial frame's record
    assert cap.problems[0].startswith("a pcap file (not pcapng): pcap keeps no directions")
    assert f"{untold} could not be (the first at offset {offset})" in cap.problems[0]
    with pytest.raises(CaptureError, match=r"link type 1 \(Ethernet\).*offset 20"):
        parse(pcap(talk, linktype=1))


def test_direction_of_tells_only_whole_frames_with_good_checksums() -> None:
    assert direction_of(cmd(IsReady(0)) + cmd(GetPin(3)), OPTS) is Direction.TO_DEVICE
    assert direction_of(ans(Response.ok()) * 2, OPTS) is Direction.TO_HOST
    assert direction_of(ans(Response.error(ErrorCode.MOTOR_ERROR)), OPTS) is Direction.TO_HOST
    assert direction_of(cmd(IsReady(0))[:9] + b"\x00", OPTS) is None
    assert direction_of(cmd(IsReady(0))[:4], OPTS) is None
    assert direction_of(b"", OPTS) is None


def test_foreign_link_types_are_left_out_or_refused_by_name(tmp_path: Path) -> None:
    ether = bytearray(encode(INFO, conversation()[:2]))
    shb_len = struct.unpack_from("<I", ether, 4)[0]
    struct.pack_into("<H", ether, shb_len + 8, 1)  # the interface: Ethernet
    path = tmp_path / "ether.pcapng"
    path.write_bytes(bytes(ether))
    with pytest.raises(TraceFileError, match=rf"link type 1 \(Ethernet\).*offset {shb_len}"):
        load([path])
    cap = parse(bytes(ether))
    assert cap.records == [] and "are not motorctl's (the first at offset" in cap.problems[0]


def _blocks(data: bytes) -> list[int]:
    """The offsets of a little-endian pcapng file's blocks."""
    offsets, pos = [], 0
    while pos < len(data):
        offsets.append(pos)
        pos += struct.unpack_from("<I", data, pos + 4)[0]
    return offsets


@pytest.mark.parametrize(
    ("length", "what"),
    [(7, "bad length"), (30, "bad length"), (0, "bad length"), (1 << 30, "ends inside a block")],
)
def test_a_block_of_a_wrong_length_is_named_by_its_offset(length: int, what: str) -> None:
    data = bytearray(encode(INFO, conversation()))
    blocks = _blocks(bytes(data))
    at = blocks[5]  # the fourth packet
    struct.pack_into("<I", data, at + 4, length)
    cap = parse(bytes(data))
    assert len(cap.records) == 3 and cap.damaged_at == at
    assert any(what in p and f"offset {at}" in p for p in cap.problems), cap.problems


def test_a_block_whose_two_lengths_differ_is_named_and_one_whose_content_lies_is_skipped() -> None:
    data = bytearray(encode(INFO, conversation()))
    blocks = _blocks(bytes(data))
    at = blocks[4]
    end = blocks[5] - 4
    struct.pack_into("<I", data, end, 999)  # its trailing length
    cap = parse(bytes(data))
    assert len(cap.records) == 2 and "at its start and 999 at its end" in cap.problems[0]
    data = bytearray(encode(INFO, conversation()))
    struct.pack_into("<I", data, at + 20, 500)  # its captured length, more than the block
    cap = parse(bytes(data))
    assert len(cap.records) == len(conversation()) - 1  # that packet alone is left out
    assert f"the packet at offset {at} claims 500 bytes" in cap.problems[0]


def test_every_truncation_point_reads_the_whole_blocks_before_it_and_names_the_cut() -> None:
    data = encode(INFO, conversation())
    blocks = _blocks(data)
    for cut in range(1, len(data)):
        if cut < blocks[1]:  # inside the section header: nothing to read
            cap = parse(data[:cut])
            assert cap.sections == [] and "its first block at offset 0" in cap.problems[0]
            continue
        cap = parse(data[:cut])
        whole = sum(1 for b in blocks[2:] if b < cut and _next(blocks, b, len(data)) <= cut)
        assert len(cap.records) == whole
        if cut in blocks:
            assert cap.problems == []
        else:
            start = max(b for b in blocks if b < cut)
            assert cap.damaged_at == start and f"offset {start}" in cap.problems[0]


def _next(blocks: list[int], b: int, end: int) -> int:
    later = [x for x in blocks if x > b]
    return later[0] if later else end


def test_rows_carry_typed_fields() -> None:
    records = [
        Record(0, IN, cmd(MoveTo(1, False, -300, 250, 3, 4))),
        Record(1 * MS, OUT, ans(Response.ok())),
        Record(2 * MS, IN, cmd(GetAbsPos(1))),
        Record(3 * MS, OUT, ans(Response.position(-300))),
        Record(4 * MS, IN, cmd(DcMove(False, 50, True))),
        Record(5 * MS, OUT, ans(Response.error(ErrorCode.MOTOR_NOT_READY))),
        Record(6 * MS, IN, cmd(GetPin(5))),
        Record(7 * MS, OUT, ans(Response.boolean(True))),
    ]
    rows = [row_json(r, 0) for r in analyse(records, INFO).rows]
    assert all(set(FIELDS) <= set(r) for r in rows)
    move, moved, read, pos, dc, e3, pin, high = rows
    assert (move["command"], move["code"], move["motor"], move["direction"]) == (
        "MoveTo",
        1,
        1,
        "down",
    )
    assert (move["position"], move["speed"], move["acc"], move["dec"]) == (-300, 250, 3, 4)
    assert moved["command"] == "MoveTo" and moved["ack"] is True and moved["position"] is None
    assert moved["rtt_us"] == 1000.0 and moved["packet"] == 0 and moved["interface"] == 0
    assert (pos["command"], pos["motor"], pos["position"]) == ("GetAbsPos", 1, -300)
    assert read["position"] is None
    assert (dc["direction"], dc["time_ms"], dc["hiz"], dc["motor"]) == ("reverse", 50, True, None)
    assert dc["text"] == "#3 DcMove(dir=reverse, time_ms=50, hiz=true)"
    assert (e3["ack"], e3["error_code"], e3["error_name"], e3["error"]) == (
        False,
        0xE3,
        "Motor not ready",
        "E3",
    )
    assert (pin["pin"], high["pin"], high["value"]) == (5, 5, 1)
