"""Made-up trace files for the trace format's tests and its readers': commands and answers
encoded with the protocol's defaults, a conversation of every kind of row, a rotating
recording by the daemon's recorder, what mergecap and ``editcap -F pcap`` make of
recordings, and a file's block offsets. No process, no clock.
"""

from __future__ import annotations

import struct
from pathlib import Path

from motorctl.daemon.link.recorder import TraceRecorder
from motorctl.protocol.capture.format import LINKTYPE_USER0, CaptureInfo, Direction, Record
from motorctl.protocol.capture.writer import RecordEncoder, header
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


def rotating(tmp_path: Path, files: int) -> tuple[TraceRecorder, Path]:
    """A recording of 40 IsReady exchanges by the daemon's recorder, flushed after each,
    in parts of at most 600 bytes, ``files`` of them kept."""
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


def pcap(records: list[Record], linktype: int = LINKTYPE_USER0) -> bytes:
    """The classic pcap file editcap -F pcap makes: no directions."""
    out = struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 0xFFFF, linktype)
    for r in records:
        out += struct.pack("<IIII", r.ts_ns // 10**9, r.ts_ns % 10**9, len(r.data), len(r.data))
        out += r.data
    return out


def block_offsets(data: bytes) -> list[int]:
    """The offsets of a little-endian pcapng file's blocks."""
    offsets, pos = [], 0
    while pos < len(data):
        offsets.append(pos)
        pos += struct.unpack_from("<I", data, pos + 4)[0]
    return offsets
