"""Writing the trace format (the package's doc): the blocks that open a file
(:func:`header`), a byte run's block (:class:`RecordEncoder`, fast: the recorders call it
for every run), a whole file (:func:`encode`) and a record's timestamp (:func:`ns_from`).

Timestamps: nanoseconds, ``origin_wall_ns + (t - origin_t)``, where ``t`` is the recorder's
monotonic clock: differences between records are differences of the monotonic clock (no NTP
step can make them jump), and the absolute values read as wall-clock time in Wireshark.

Pure: bytes out, no file, no clock; a :class:`RecordEncoder` is owned by the thread that
calls it (the link thread's recorder, the tap's).
"""

from __future__ import annotations

import struct

from motorctl.protocol.capture.format import (
    BYTE_ORDER_MAGIC,
    EPB,
    EPB_DROPCOUNT,
    EPB_FLAGS,
    IDB,
    IF_DESCRIPTION,
    IF_NAME,
    IF_TSRESOL,
    LINKTYPE_USER0,
    OPT_COMMENT,
    OPT_END,
    SHB,
    SHB_OS,
    SHB_USERAPPL,
    CaptureInfo,
    Record,
)


def _option(code: int, value: bytes) -> bytes:
    pad = -len(value) % 4
    return struct.pack("<HH", code, len(value)) + value + bytes(pad)


def _block(kind: int, body: bytes) -> bytes:
    total = 12 + len(body)
    return struct.pack("<II", kind, total) + body + struct.pack("<I", total)


def header(info: CaptureInfo, os_name: str = "") -> bytes:
    """The Section Header Block and the Interface Description Block that open every file."""
    comment = info.comment().encode()
    shb_opts = _option(OPT_COMMENT, comment)
    shb_opts += _option(SHB_USERAPPL, info.application.encode())
    if os_name:
        shb_opts += _option(SHB_OS, os_name.encode())
    shb_opts += _option(OPT_END, b"")
    shb = _block(SHB, struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + shb_opts)
    idb_opts = _option(OPT_COMMENT, comment)
    idb_opts += _option(IF_NAME, (info.port or "motorctl link").encode())
    idb_opts += _option(
        IF_DESCRIPTION,
        b"motorctl UART protocol: 10-byte commands in, 5-byte answers out (docs/trace.md)",
    )
    idb_opts += _option(IF_TSRESOL, bytes([9]))
    idb_opts += _option(OPT_END, b"")
    idb = _block(IDB, struct.pack("<HHI", LINKTYPE_USER0, 0, 0) + idb_opts)
    return shb + idb


_EPB_HEAD = struct.Struct("<IIIIIII")


class RecordEncoder:
    """Encodes byte runs as Enhanced Packet Blocks, fast: the link thread calls it for every
    run read or written, so the parts that depend only on a run's length and direction are
    built once and kept (a few dozen lengths occur: commands, answers and their batches).
    Owned by the thread that calls it."""

    def __init__(self) -> None:
        self._tails: dict[tuple[int, int], tuple[int, bytes]] = {}

    def _tail(self, length: int, direction: int) -> tuple[int, bytes]:
        pad = -length % 4
        opts = _option(EPB_FLAGS, struct.pack("<I", direction)) + _option(OPT_END, b"")
        total = _EPB_HEAD.size + length + pad + len(opts) + 4
        return total, bytes(pad) + opts + struct.pack("<I", total)

    def encode(
        self, ts_ns: int, direction: int, data: bytes | bytearray, dropped: int = 0
    ) -> bytes:
        """One block for ``data`` (a run of ``direction``) recorded at ``ts_ns``."""
        length = len(data)
        if dropped:
            return self._encode_dropped(ts_ns, direction, bytes(data), dropped)
        key = (length, direction)
        tail = self._tails.get(key)
        if tail is None:
            tail = self._tails[key] = self._tail(length, direction)
        total, end = tail
        return b"".join(
            (
                _EPB_HEAD.pack(EPB, total, 0, ts_ns >> 32, ts_ns & 0xFFFFFFFF, length, length),
                data,
                end,
            )
        )

    @staticmethod
    def _encode_dropped(ts_ns: int, direction: int, data: bytes, dropped: int) -> bytes:
        opts = (
            _option(EPB_FLAGS, struct.pack("<I", direction))
            + _option(EPB_DROPCOUNT, struct.pack("<Q", dropped))
            + _option(OPT_END, b"")
        )
        body = (
            struct.pack("<IIIII", 0, ts_ns >> 32, ts_ns & 0xFFFFFFFF, len(data), len(data))
            + data
            + bytes(-len(data) % 4)
            + opts
        )
        return _block(EPB, body)


def encode(info: CaptureInfo, records: list[Record]) -> bytes:
    """A whole file: header and records (tests, tools; the recorders stream instead)."""
    enc = RecordEncoder()
    return header(info) + b"".join(
        enc.encode(r.ts_ns, r.direction, r.data, r.dropped) for r in records
    )


def ns_from(origin_wall_ns: int, origin_t: float, t: float) -> int:
    """The timestamp of a record taken at monotonic ``t`` (see the module doc)."""
    return origin_wall_ns + round((t - origin_t) * 1e9)
