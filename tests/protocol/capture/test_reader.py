"""The trace format's reader (protocol/capture/reader.py) on made-up files: refused files
named, files cut or damaged anywhere read up to the damage and the damage named by its
offset, pcap files and foreign link types, directions told from the bytes. No process, no
clock. The same files as users meet them: tests/client/test_trace_files.py."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from motorctl.protocol.capture.format import CaptureError, Direction, Record
from motorctl.protocol.capture.reader import direction_of, parse
from motorctl.protocol.capture.writer import encode, header
from motorctl.protocol.codec import ErrorCode, GetPin, IsReady, Response
from tests.support.traces import (
    IN,
    INFO,
    MS,
    OPTS,
    OUT,
    ans,
    block_offsets,
    cmd,
    conversation,
    pcap,
)


def test_a_file_cut_mid_block_gives_its_complete_blocks_and_says_so() -> None:
    records = [Record(i * MS, IN, bytes([i]) * 10) for i in range(5)]
    data = encode(INFO, records)
    cap = parse(data[:-7])
    assert cap.records == records[:4]
    assert cap.truncated_bytes > 0 and "ends inside a block" in cap.problems[0]


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


def test_packets_of_a_foreign_link_type_are_left_out_by_name() -> None:
    ether = bytearray(encode(INFO, conversation()[:2]))
    shb_len = struct.unpack_from("<I", ether, 4)[0]
    struct.pack_into("<H", ether, shb_len + 8, 1)  # the interface: Ethernet
    cap = parse(bytes(ether))
    assert cap.records == [] and "are not motorctl's (the first at offset" in cap.problems[0]


@pytest.mark.parametrize(
    ("length", "what"),
    [(7, "bad length"), (30, "bad length"), (0, "bad length"), (1 << 30, "ends inside a block")],
)
def test_a_block_of_a_wrong_length_is_named_by_its_offset(length: int, what: str) -> None:
    data = bytearray(encode(INFO, conversation()))
    blocks = block_offsets(bytes(data))
    at = blocks[5]  # the fourth packet
    struct.pack_into("<I", data, at + 4, length)
    cap = parse(bytes(data))
    assert len(cap.records) == 3 and cap.damaged_at == at
    assert any(what in p and f"offset {at}" in p for p in cap.problems), cap.problems


def test_a_block_whose_two_lengths_differ_is_named_and_one_whose_content_lies_is_skipped() -> None:
    data = bytearray(encode(INFO, conversation()))
    blocks = block_offsets(bytes(data))
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
    blocks = block_offsets(data)
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
