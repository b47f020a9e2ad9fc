"""The trace format's writer (protocol/capture/writer.py): its files are standard pcapng
of the USER0 link type, and the reader gets back every run as written. No process, no clock."""

from __future__ import annotations

import struct

from motorctl.protocol.capture.format import LINKTYPE_USER0, Record
from motorctl.protocol.capture.reader import parse
from motorctl.protocol.capture.writer import encode, header
from tests.support.traces import IN, INFO, OUT


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


def test_header_is_standard_pcapng_with_the_user0_link_type() -> None:
    data = header(INFO)
    kind, total, magic, major, minor = struct.unpack_from("<IIIHH", data)
    assert (kind, magic, major, minor) == (0x0A0D0D0A, 0x1A2B3C4D, 1, 0)
    idb = data[total:]
    assert struct.unpack_from("<IIH", idb)[0] == 1
    assert struct.unpack_from("<H", idb, 8)[0] == LINKTYPE_USER0 == 147
