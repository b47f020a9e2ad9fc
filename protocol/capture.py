"""The trace file format (docs/trace.md): pcapng, one interface of link type LINKTYPE_USER0.

Why it lives in protocol/: the daemon writes it (``motorctld --trace``), the client side
writes and reads it (``motorctl tap``, ``motorctl trace``, ``motorctl replay``), and
``client -> protocol <- daemon`` is the one room both may import. It is a pure codec like
the rest of the room: bytes in, bytes out, no file, no clock, no thread. Callers read and
write the files and pass the timestamps in (from the clock that timed the byte runs).

What a file holds:

- A Section Header Block whose comment carries the settings a reader needs to frame and
  decode the bytes again: ``motorctl-trace/1 role=daemon checksum=crc8 crc_covers_ack=0
  strict_padding=1 frame_gap_ms=10``, plus the recording program and the port.
- One Interface Description Block: link type 147 (LINKTYPE_USER0, the range pcap leaves to
  private use), no snap length, timestamps in nanoseconds (``if_tsresol`` = 9).
- One Enhanced Packet Block per byte run, as it was read from or written to the port, with
  its direction in ``epb_flags`` (bits 0-1): inbound (1) = host -> device, a command's bytes;
  outbound (2) = device -> host, an answer's bytes. Directions are always named from the
  device's side, in the daemon's trace and in the tap's alike. ``epb_dropcount`` says how
  many byte runs a writer that fell behind left out just before this one.

Timestamps: nanoseconds, ``origin_wall_ns + (t - origin_t)``, where ``t`` is the recorder's
monotonic clock: differences between records are differences of the monotonic clock (no NTP
step can make them jump), and the absolute values read as wall-clock time in Wireshark.

Readers accept both byte orders, several sections in one file (files concatenated with
``cat``) and a file cut short mid-block (a writer killed mid-write: the complete blocks are
read, the rest is reported).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field, replace
from enum import IntEnum

from motorctl.protocol.codec import CodecOptions
from motorctl.protocol.crc import CHECKSUM_DEFAULT, checksum_by_name

FORMAT = "motorctl-trace/1"
"""The first word of the section comment; the number is the format's version."""

LINKTYPE_USER0 = 147
SUFFIX = ".pcapng"

SHB = 0x0A0D0D0A
IDB = 0x00000001
EPB = 0x00000006
SPB = 0x00000003
BYTE_ORDER_MAGIC = 0x1A2B3C4D

OPT_END = 0
OPT_COMMENT = 1
SHB_HARDWARE = 2
SHB_OS = 3
SHB_USERAPPL = 4
IF_NAME = 2
IF_DESCRIPTION = 3
IF_TSRESOL = 9
EPB_FLAGS = 2
EPB_DROPCOUNT = 4


class Direction(IntEnum):
    """A byte run's direction, as ``epb_flags`` bits 0-1 say it (the device's view)."""

    TO_DEVICE = 1  # inbound: host -> device (commands)
    TO_HOST = 2  # outbound: device -> host (answers)

    @property
    def arrow(self) -> str:
        """``->`` for host -> device, ``<-`` for device -> host."""
        return "->" if self is Direction.TO_DEVICE else "<-"


class CaptureError(Exception):
    """Not a trace file this reader can use; the message says why."""


def _flag(value: bool) -> str:
    return "1" if value else "0"


@dataclass(frozen=True)
class CaptureInfo:
    """What a reader needs besides the bytes: how frames were cut and checked."""

    role: str = "daemon"  # "daemon" (motorctld --trace) or "tap" (motorctl tap)
    checksum: str = CHECKSUM_DEFAULT
    crc_covers_ack: bool = False
    strict_padding: bool = True
    frame_gap_ms: float = 10.0
    port: str = ""  # the port recorded (the daemon's) or "host <-> device" (the tap's)
    application: str = "motorctl"

    def comment(self) -> str:
        """The section comment: ``motorctl-trace/1 key=value ...`` (no spaces in values)."""
        return (
            f"{FORMAT} role={self.role} checksum={self.checksum.replace(' ', '')} "
            f"crc_covers_ack={_flag(self.crc_covers_ack)} "
            f"strict_padding={_flag(self.strict_padding)} "
            f"frame_gap_ms={self.frame_gap_ms:g}"
        )

    @classmethod
    def from_comment(cls, text: str, port: str = "", application: str = "") -> CaptureInfo:
        """Parse :meth:`comment`'s text; CaptureError if it is not one or a value is bad.
        Unknown keys are ignored (a later minor version may add some)."""
        words = text.split()
        if not words or not words[0].startswith("motorctl-trace/"):
            raise CaptureError(f"section comment {text[:60]!r} is not a {FORMAT} header")
        version = words[0].split("/", 1)[1]
        if version != FORMAT.split("/", 1)[1]:
            raise CaptureError(f"trace format version {version}; this reader knows {FORMAT}")
        values = dict(w.split("=", 1) for w in words[1:] if "=" in w)
        try:
            info = cls(
                role=values.get("role", "daemon"),
                checksum=values.get("checksum", CHECKSUM_DEFAULT),
                crc_covers_ack=values.get("crc_covers_ack", "0") == "1",
                strict_padding=values.get("strict_padding", "1") == "1",
                frame_gap_ms=float(values.get("frame_gap_ms", "10")),
                port=port,
                application=application or "motorctl",
            )
            info.codec_options()
        except ValueError as exc:
            raise CaptureError(f"bad value in the section comment {text!r}: {exc}") from None
        return info

    def codec_options(self) -> CodecOptions:
        """The codec settings the recorded link used (ValueError: unknown checksum name)."""
        return CodecOptions(
            crc=checksum_by_name(self.checksum),
            crc_covers_ack=self.crc_covers_ack,
            strict_padding=self.strict_padding,
        )


@dataclass(frozen=True)
class Record:
    """One byte run: when (ns, see the module doc), which way, the bytes, runs left out
    just before it (``dropped``)."""

    ts_ns: int
    direction: Direction
    data: bytes
    dropped: int = 0


# --- writing ----------------------------------------------------------------------------------


def _option(code: int, value: bytes) -> bytes:
    pad = -len(value) % 4
    return struct.pack("<HH", code, len(value)) + value + bytes(pad)


def _block(kind: int, body: bytes) -> bytes:
    total = 12 + len(body)
    return struct.pack("<II", kind, total) + body + struct.pack("<I", total)


def header(info: CaptureInfo, os_name: str = "") -> bytes:
    """The Section Header Block and the Interface Description Block that open every file."""
    shb_opts = _option(OPT_COMMENT, info.comment().encode())
    shb_opts += _option(SHB_USERAPPL, info.application.encode())
    if os_name:
        shb_opts += _option(SHB_OS, os_name.encode())
    shb_opts += _option(OPT_END, b"")
    shb = _block(SHB, struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + shb_opts)
    idb_opts = _option(IF_NAME, (info.port or "motorctl link").encode())
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


# --- reading ----------------------------------------------------------------------------------


@dataclass
class Capture:
    """What a file held: the settings (None: a pcapng without a motorctl header), the byte
    runs in file order, and what could not be read (a cut-off end, foreign blocks)."""

    info: CaptureInfo | None
    records: list[Record] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    truncated_bytes: int = 0


def _options(data: bytes, order: str) -> dict[int, list[bytes]]:
    out: dict[int, list[bytes]] = {}
    pos = 0
    while pos + 4 <= len(data):
        code, length = struct.unpack_from(order + "HH", data, pos)
        pos += 4
        if code == OPT_END:
            break
        out.setdefault(code, []).append(bytes(data[pos : pos + length]))
        pos += length + (-length % 4)
    return out


def _resolution_ns(raw: bytes | None) -> tuple[int, int]:
    """(numerator, denominator) turning a timestamp into ns, from ``if_tsresol``."""
    value = raw[0] if raw else 6
    if value & 0x80:
        return 10**9, 2 ** (value & 0x7F)
    exp = value & 0x7F
    return (10 ** (9 - exp), 1) if exp <= 9 else (1, 10 ** (exp - 9))


def parse(data: bytes) -> Capture:
    """Read a trace file's bytes; CaptureError if it is not pcapng at all."""
    if len(data) < 12 or struct.unpack_from("<I", data, 0)[0] != SHB:
        raise CaptureError("not a pcapng file (no Section Header Block at its start)")
    cap = Capture(info=None)
    pos = 0
    order = "<"
    interfaces: list[tuple[int, tuple[int, int]]] = []  # (link type, resolution)
    foreign = 0
    while pos < len(data):
        if len(data) - pos < 12:
            cap.truncated_bytes = len(data) - pos
            break
        kind = struct.unpack_from("<I", data, pos)[0]
        if kind == SHB:
            magic = data[pos + 8 : pos + 12]
            if magic == struct.pack("<I", BYTE_ORDER_MAGIC):
                order = "<"
            elif magic == struct.pack(">I", BYTE_ORDER_MAGIC):
                order = ">"
            else:
                raise CaptureError(f"bad byte-order magic at offset {pos}")
            interfaces = []
        else:
            kind = struct.unpack_from(order + "I", data, pos)[0]
        total = struct.unpack_from(order + "I", data, pos + 4)[0]
        if total < 12 or total % 4:
            raise CaptureError(f"block at offset {pos} has a bad length {total}")
        if pos + total > len(data):
            cap.truncated_bytes = len(data) - pos
            break
        body = data[pos + 8 : pos + total - 4]
        if kind == SHB:
            opts = _options(body[16:], order)
            comments = [c.decode(errors="replace") for c in opts.get(OPT_COMMENT, [])]
            appl = b"".join(opts.get(SHB_USERAPPL, [])).decode(errors="replace")
            for text in comments:
                if text.startswith("motorctl-trace/") and cap.info is None:
                    cap.info = CaptureInfo.from_comment(text, application=appl)
        elif kind == IDB:
            linktype = struct.unpack_from(order + "H", body, 0)[0]
            opts = _options(body[8:], order)
            res = _resolution_ns(opts.get(IF_TSRESOL, [None])[0])
            interfaces.append((linktype, res))
            names = opts.get(IF_NAME)
            if names and cap.info is not None and not cap.info.port:
                cap.info = _with_port(cap.info, names[0].decode(errors="replace"))
        elif kind == EPB:
            iface, hi, lo, caplen, origlen = struct.unpack_from(order + "IIIII", body, 0)
            if iface >= len(interfaces):
                cap.problems.append(
                    f"packet at offset {pos} names interface {iface}, which is not described"
                )
            elif interfaces[iface][0] != LINKTYPE_USER0:
                foreign += 1
            else:
                payload = bytes(body[20 : 20 + caplen])
                opts = _options(body[20 + caplen + (-caplen % 4) :], order)
                flags = opts.get(EPB_FLAGS)
                bits = struct.unpack(order + "I", flags[0])[0] & 3 if flags else 0
                drops = opts.get(EPB_DROPCOUNT)
                dropped = struct.unpack(order + "Q", drops[0])[0] if drops else 0
                if bits not in (1, 2):
                    cap.problems.append(
                        f"packet at offset {pos} has no direction (epb_flags {bits}); left out"
                    )
                else:
                    if caplen != origlen:
                        cap.problems.append(
                            f"packet at offset {pos} was cut to {caplen} of {origlen} bytes"
                        )
                    num, den = interfaces[iface][1]
                    ts = ((hi << 32) | lo) * num // den
                    cap.records.append(Record(ts, Direction(bits), payload, dropped))
        # other blocks (statistics, name resolution, custom): skipped
        pos += total
    if foreign:
        cap.problems.append(f"{foreign} packets of other link types left out")
    if cap.truncated_bytes:
        cap.problems.append(
            f"the file ends inside a block: its last {cap.truncated_bytes} "
            "bytes left out (a writer stopped mid-write)"
        )
    return cap


def _with_port(info: CaptureInfo, port: str) -> CaptureInfo:
    return replace(info, port=port)


def ns_from(origin_wall_ns: int, origin_t: float, t: float) -> int:
    """The timestamp of a record taken at monotonic ``t`` (see the module doc)."""
    return origin_wall_ns + round((t - origin_t) * 1e9)
