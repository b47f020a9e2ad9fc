"""The trace file format (docs/trace.md): pcapng, interfaces of link type LINKTYPE_USER0.

Over 500 lines on purpose: the format's writer and its one reader (pcapng and classic pcap,
every kind of damage named by its offset) side by side, so that what one writes the other
reads; trace and replay both read through :func:`parse`.

Why it lives in protocol/: the daemon writes it (``motorctld --trace``), the client side
writes and reads it (``motorctl tap``, ``motorctl trace``, ``motorctl replay``), and
``client -> protocol <- daemon`` is the one room both may import. It is a pure codec like
the rest of the room: bytes in, bytes out, no file, no clock, no thread. Callers read and
write the files and pass the timestamps (and a session's name) in.

What a file holds:

- A Section Header Block whose comment carries the settings a reader needs to frame and
  decode the bytes again: ``motorctl-trace/1 role=daemon checksum=crc8 crc_covers_ack=0
  strict_padding=1 frame_gap_ms=10 session=3f2a9c01d4e5 part=1``, plus the recording
  program and the port. ``session`` names one recording (a daemon's run, a tap's run) and
  ``part`` numbers its files from 1 (the daemon's trace rotates), so a missing part and a
  missing start are noticed.
- One Interface Description Block: link type 147 (LINKTYPE_USER0, the range pcap leaves to
  private use), no snap length, timestamps in nanoseconds (``if_tsresol`` = 9), and the same
  settings comment again as its own ``opt_comment``: mergecap keeps only the first file's
  section comment, each interface keeps its own.
- One Enhanced Packet Block per byte run, as it was read from or written to the port, with
  its direction in ``epb_flags`` (bits 0-1): inbound (1) = host -> device, a command's bytes;
  outbound (2) = device -> host, an answer's bytes. Directions are always named from the
  device's side, in the daemon's trace and in the tap's alike. ``epb_dropcount`` says how
  many byte runs a writer that fell behind left out just before this one.

Timestamps: nanoseconds, ``origin_wall_ns + (t - origin_t)``, where ``t`` is the recorder's
monotonic clock: differences between records are differences of the monotonic clock (no NTP
step can make them jump), and the absolute values read as wall-clock time in Wireshark.

Reading (:func:`parse`) takes any bytes and never fails other than with
:class:`CaptureError` (not a capture at all) or a :class:`Capture` whose ``problems`` name
each damage by its byte offset: both byte orders, several sections (files concatenated with
``cat``), several interfaces (mergecap's output: each is its own link, ``Record.interface``),
a file cut short or damaged (what comes before is read, the rest is reported), classic pcap
files (which keep no directions: told from the bytes where a run is whole commands or whole
answers with good checksums, else left out and counted).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field, replace
from enum import IntEnum

from motorctl.protocol.codec import FRAME_LEN, RESPONSE_LEN, CodecOptions, CommandCode, ErrorCode
from motorctl.protocol.crc import CHECKSUM_DEFAULT, checksum_by_name

FORMAT = "motorctl-trace/1"
"""The first word of the section comment; the number is the format's version."""

LINKTYPE_USER0 = 147
SUFFIX = ".pcapng"

SHB = 0x0A0D0D0A
IDB = 0x00000001
OPB = 0x00000002  # the obsolete Packet Block
SPB = 0x00000003
EPB = 0x00000006
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

#: classic pcap's magic numbers (as the first four bytes read) -> (byte order, ns resolution)
PCAP_MAGIC = {
    b"\xd4\xc3\xb2\xa1": ("<", False),
    b"\xa1\xb2\xc3\xd4": (">", False),
    b"\x4d\x3c\xb2\xa1": ("<", True),
    b"\xa1\xb2\x3c\x4d": (">", True),
}
#: link types a user may meet, for messages
LINKTYPE_NAMES = {
    0: "NULL",
    1: "Ethernet",
    101: "raw IP",
    113: "Linux cooked (SLL)",
    147: "USER0",
    276: "Linux cooked v2 (SLL2)",
    **{147 + i: f"USER{i}" for i in range(1, 16)},
}
MAX_RECORD = 1 << 24  # a pcap record longer than this is damage, not data


def linktype_name(linktype: int) -> str:
    name = LINKTYPE_NAMES.get(linktype)
    return f"link type {linktype}" + (f" ({name})" if name else "")


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
    """What a reader needs besides the bytes: how frames were cut and checked, and which
    recording and which part of it a file is."""

    role: str = "daemon"  # "daemon" (motorctld --trace) or "tap" (motorctl tap)
    checksum: str = CHECKSUM_DEFAULT
    crc_covers_ack: bool = False
    strict_padding: bool = True
    frame_gap_ms: float = 10.0
    port: str = ""  # the port recorded (the daemon's) or "host <-> device" (the tap's)
    application: str = "motorctl"
    session: str = ""  # names one recording (no spaces); "" in files of older versions
    part: int = 0  # the file's number within its session, from 1; 0: not numbered

    def comment(self) -> str:
        """The section comment: ``motorctl-trace/1 key=value ...`` (no spaces in values)."""
        text = (
            f"{FORMAT} role={self.role} checksum={self.checksum.replace(' ', '')} "
            f"crc_covers_ack={_flag(self.crc_covers_ack)} "
            f"strict_padding={_flag(self.strict_padding)} "
            f"frame_gap_ms={self.frame_gap_ms:g}"
        )
        if self.session:
            text += f" session={self.session} part={self.part}"
        return text

    def settings(self) -> tuple[str, bool, bool, float]:
        """What decoding depends on: two files with the same settings decode alike."""
        return (self.checksum, self.crc_covers_ack, self.strict_padding, self.frame_gap_ms)

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
                session=values.get("session", ""),
                part=int(values.get("part", "0")),
            )
            info.codec_options()
            if not info.frame_gap_ms >= 0 or info.part < 0:
                raise ValueError("frame_gap_ms and part cannot be negative")
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
    just before it (``dropped``), the interface it was recorded on (its number within its
    section: Wireshark's ``frame.interface_id``), and where it is in its file (``packet``:
    its number among the file's packets, 1 = the first, as Wireshark's ``frame.number``;
    ``offset``: its block's byte offset)."""

    ts_ns: int
    direction: Direction
    data: bytes
    dropped: int = 0
    interface: int = 0
    packet: int = field(default=0, compare=False)
    offset: int = field(default=-1, compare=False)


# --- writing ----------------------------------------------------------------------------------


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


# --- reading ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Interface:
    """An interface as its description says: its number within its section (the packets'
    interface id), link type, name (``if_name``) and motorctl settings (its own comment, else
    its section's; None: neither has one)."""

    number: int
    link_type: int
    name: str
    info: CaptureInfo | None
    offset: int = field(default=-1, compare=False)  # its description's, in its file


@dataclass
class Section:
    """One section of a file (a file written by one recorder, or one of several files put
    together with ``cat``): where it starts, its settings, its interfaces."""

    offset: int
    info: CaptureInfo | None
    interfaces: list[Interface] = field(default_factory=list)


@dataclass
class Capture:
    """What a file held: the settings of its first section (None: no motorctl header), the
    byte runs in file order, its sections and interfaces, and what could not be read, each
    problem naming its byte offset. ``damaged_at``: where reading had to stop (a block cut
    off or broken), None when the file was read to its end."""

    info: CaptureInfo | None
    records: list[Record] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    truncated_bytes: int = 0
    format: str = "pcapng"
    sections: list[Section] = field(default_factory=list)
    damaged_at: int | None = None
    packets: int = 0  # packet blocks seen, of any interface (Wireshark numbers them all)
    size: int = 0  # the file's length in bytes

    @property
    def interfaces(self) -> list[Interface]:
        """Each interface number once (its first description), in number order."""
        seen: dict[int, Interface] = {}
        for section in self.sections:
            for iface in section.interfaces:
                seen.setdefault(iface.number, iface)
        return [seen[n] for n in sorted(seen)]


class _Bad(Exception):
    """A block whose contents cannot be read (its framing is sound: the next one can)."""


class _Tally:
    """Problems, with repeats of a kind counted instead of listed."""

    def __init__(self) -> None:
        self.first: dict[str, str] = {}
        self.count: dict[str, int] = {}

    def add(self, kind: str, text: str) -> None:
        self.first.setdefault(kind, text)
        self.count[kind] = self.count.get(kind, 0) + 1

    def lines(self) -> list[str]:
        out = []
        for kind, text in self.first.items():
            more = self.count[kind] - 1
            out.append(text + (f" (and {more} more like it)" if more else ""))
        return out


def _options(data: bytes, order: str, base: int) -> dict[int, list[bytes]]:
    """The options in ``data`` (``base``: its offset in the file, for messages)."""
    out: dict[int, list[bytes]] = {}
    pos = 0
    while pos + 4 <= len(data):
        code, length = struct.unpack_from(order + "HH", data, pos)
        if code == OPT_END:
            break
        if pos + 4 + length > len(data):
            raise _Bad(
                f"option {code} at offset {base + pos} is {length} bytes long, past its block"
            )
        out.setdefault(code, []).append(bytes(data[pos + 4 : pos + 4 + length]))
        pos += 4 + length + (-length % 4)
    return out


def _resolution_ns(raw: bytes | None) -> tuple[int, int]:
    """(numerator, denominator) turning a timestamp into ns, from ``if_tsresol``."""
    value = raw[0] if raw else 6
    if value & 0x80:
        return 10**9, 2 ** (value & 0x7F)
    exp = value & 0x7F
    return (10 ** (9 - exp), 1) if exp <= 9 else (1, 10 ** (exp - 9))


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace").rstrip("\x00")


def _info_of(comments: list[bytes], port: str, application: str) -> CaptureInfo | None:
    for raw in comments:
        text = _text(raw)
        if text.startswith("motorctl-trace/"):
            return CaptureInfo.from_comment(text, port=port, application=application)
    return None


_CODES = frozenset(int(c) for c in CommandCode)
_ERROR_CODES = frozenset(int(c) for c in ErrorCode)


def _command_ok(chunk: bytes, opts: CodecOptions) -> bool:
    if chunk[0] not in _CODES:
        return False
    return opts.crc is None or opts.crc.compute(chunk[: FRAME_LEN - 1]) == chunk[FRAME_LEN - 1]


def _answer_ok(chunk: bytes, opts: CodecOptions) -> bool:
    if chunk[0] not in (0, 1) or (chunk[0] == 0 and chunk[1] not in _ERROR_CODES):
        return False
    if opts.crc is None:
        return True
    covered = chunk[:4] if opts.crc_covers_ack else chunk[1:4]
    return opts.crc.compute(covered) == chunk[4]


_DIRECTIONS = (None, Direction.TO_DEVICE, Direction.TO_HOST, None)  # by epb_flags bits 0-1


def direction_of(data: bytes, opts: CodecOptions) -> Direction | None:
    """A run's direction told from its bytes, where they tell it: whole command frames with
    known codes and good checksums are host -> device, whole answers (R0 0 or 1, an error's
    code known, good checksums) device -> host; None when it is neither or could be both (a
    frame cut across runs, a bad checksum, checksum "none" with ambiguous bytes)."""
    if not data:
        return None
    as_cmd = len(data) % FRAME_LEN == 0 and all(
        _command_ok(data[i : i + FRAME_LEN], opts) for i in range(0, len(data), FRAME_LEN)
    )
    as_ans = len(data) % RESPONSE_LEN == 0 and all(
        _answer_ok(data[i : i + RESPONSE_LEN], opts) for i in range(0, len(data), RESPONSE_LEN)
    )
    if as_cmd == as_ans:
        return None
    return Direction.TO_DEVICE if as_cmd else Direction.TO_HOST


def parse(data: bytes) -> Capture:
    """Read a trace file's bytes: pcapng (any byte order, sections, interfaces) or classic
    pcap. CaptureError only when it is neither (or a pcap of another link type); any damage
    after the file's first bytes is a problem naming its offset, and what was read before
    it is kept."""
    if not data:
        raise CaptureError("the file is empty")
    pcap = PCAP_MAGIC.get(bytes(data[:4]))
    if pcap is not None:
        return _parse_pcap(data, *pcap)
    if len(data) < 4 and struct.pack("<I", SHB).startswith(bytes(data)):
        return _Reader(data).read()  # a pcapng file cut inside its first block
    if len(data) < 4 or struct.unpack_from("<I", data, 0)[0] != SHB:
        raise CaptureError(
            f"not a pcapng or pcap file: its first bytes (offset 0) are "
            f"{bytes(data[:8]).hex(' ')} (a pcapng file starts with 0a 0d 0d 0a, a pcap file "
            "with d4 c3 b2 a1 or a1 b2 c3 d4)"
        )
    return _Reader(data).read()


class _Reader:
    """One pass over a pcapng file's blocks."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.cap = Capture(info=None, size=len(data))
        self.tally = _Tally()
        self._byte_order("<")
        self.section: Section | None = None
        self.resolutions: list[tuple[int, int]] = []
        self.untold = 0
        self.first_untold = -1

    def _byte_order(self, order: str) -> None:
        self.order = order
        self.epb_head = struct.Struct(order + "IIIII")
        self.flags_only = struct.Struct(order + "HHIHH")
        self.u32 = struct.Struct(order + "I")
        self.u64 = struct.Struct(order + "Q")

    def read(self) -> Capture:
        data, cap = self.data, self.cap
        pos = 0
        while pos < len(data):
            left = len(data) - pos
            if left < 12:
                self._cut(pos, f"{left} bytes, too few for a block")
                break
            kind = struct.unpack_from("<I", data, pos)[0]
            if kind == SHB:
                magic = bytes(data[pos + 8 : pos + 12])
                if magic == struct.pack("<I", BYTE_ORDER_MAGIC):
                    self._byte_order("<")
                elif magic == struct.pack(">I", BYTE_ORDER_MAGIC):
                    self._byte_order(">")
                else:
                    self._damage(
                        pos,
                        f"a section header at offset {pos} has a bad byte-order "
                        f"magic ({magic.hex(' ')})",
                    )
                    break
            else:
                kind = struct.unpack_from(self.order + "I", data, pos)[0]
            total = struct.unpack_from(self.order + "I", data, pos + 4)[0]
            if total < 12 or total % 4:
                self._damage(
                    pos, f"the block at offset {pos} (type 0x{kind:08x}) has a bad length ({total})"
                )
                break
            if total > left:
                self._cut(pos, f"a block of {total} bytes (type 0x{kind:08x}), {left} there")
                break
            trailer = struct.unpack_from(self.order + "I", data, pos + total - 4)[0]
            if trailer != total:
                self._damage(
                    pos,
                    f"the block at offset {pos} (type 0x{kind:08x}) says it is "
                    f"{total} bytes long at its start and {trailer} at its end",
                )
                break
            body = bytes(data[pos + 8 : pos + total - 4])
            try:
                self._block(kind, body, pos)
            except _Bad as exc:
                self.tally.add(f"bad{kind}", f"{exc}; the block at offset {pos} is left out")
            pos += total
        if self.untold:
            self.tally.add(
                "untold",
                f"{self.untold} packets carry no direction (epb_flags) and their bytes do not "
                f"tell it (the first at offset {self.first_untold}); left out",
            )
        cap.problems = self.tally.lines() + cap.problems
        return cap

    def _cut(self, pos: int, what: str) -> None:
        cap = self.cap
        cap.truncated_bytes = len(self.data) - pos
        cap.damaged_at = pos
        where = "its first block" if pos == 0 else "a block"
        cap.problems.append(
            f"the file ends inside {where} at offset {pos} ({what}): its last "
            f"{cap.truncated_bytes} bytes left out (a writer stopped mid-write, or the file "
            "was cut)"
        )

    def _damage(self, pos: int, what: str) -> None:
        if pos == 0:
            raise CaptureError(f"damaged at offset 0: {what}")
        self.cap.damaged_at = pos
        self.cap.problems.append(
            f"damaged at offset {pos}: {what}; the {len(self.data) - pos} bytes from there on "
            "cannot be read"
        )

    def _block(self, kind: int, body: bytes, pos: int) -> None:
        if kind == SHB:
            self._section(body, pos)
        elif self.section is None:
            raise _Bad(f"a block at offset {pos} comes before any section header")
        elif kind == IDB:
            self._interface(body, pos)
        elif kind == EPB:
            self._packet(body, pos)
        elif kind in (SPB, OPB):
            self.cap.packets += 1
            self.tally.add(
                f"kind{kind}",
                f"a {'simple' if kind == SPB else 'obsolete'} packet block at offset {pos} "
                "(no direction, no interface of its own) left out",
            )
        # other blocks (statistics, name resolution, custom): nothing a reader needs

    def _section(self, body: bytes, pos: int) -> None:
        if len(body) < 16:
            raise _Bad(f"a section header at offset {pos} is too short")
        try:
            opts = _options(body[16:], self.order, pos + 24)
        except _Bad:
            opts = {}
            self.tally.add("shbopts", f"the section header at offset {pos} has bad options")
        appl = _text(b"".join(opts.get(SHB_USERAPPL, [])))
        self.section = Section(pos, None)
        self.cap.sections.append(self.section)
        self.resolutions = []
        try:
            self.section.info = _info_of(opts.get(OPT_COMMENT, []), "", appl)
        except CaptureError as exc:
            if pos == 0:
                raise CaptureError(f"the section header at offset 0: {exc}") from None
            self.tally.add(
                f"shb{pos}",
                f"the section at offset {pos}: {exc}; read as if it had no motorctl header",
            )
        if self.cap.info is None and self.section.info is not None:
            self.cap.info = self.section.info

    def _interface(self, body: bytes, pos: int) -> None:
        assert self.section is not None
        if len(body) < 8:
            raise _Bad(f"an interface description at offset {pos} is too short")
        linktype = struct.unpack_from(self.order + "H", body, 0)[0]
        opts = _options(body[8:], self.order, pos + 16)
        names = opts.get(IF_NAME)
        name = _text(names[0]) if names else ""
        section_info = self.section.info
        appl = section_info.application if section_info is not None else ""
        try:
            info = _info_of(opts.get(OPT_COMMENT, []), name, appl)
        except CaptureError as exc:
            self.tally.add(f"idb{pos}", f"the interface at offset {pos}: {exc}")
            info = None
        if info is None and section_info is not None:
            info = replace(section_info, port=name or section_info.port)
        number = len(self.section.interfaces)
        self.section.interfaces.append(Interface(number, linktype, name, info, pos))
        self.resolutions.append(_resolution_ns(opts.get(IF_TSRESOL, [None])[0]))
        if self.cap.info is not None and not self.cap.info.port and name:
            self.cap.info = replace(self.cap.info, port=name)

    def _packet(self, body: bytes, pos: int) -> None:
        assert self.section is not None
        self.cap.packets += 1
        if len(body) < 20:
            raise _Bad(f"a packet block at offset {pos} is too short")
        iface, hi, lo, caplen, origlen = self.epb_head.unpack_from(body, 0)
        if caplen > len(body) - 20:
            raise _Bad(f"the packet at offset {pos} claims {caplen} bytes, more than its block")
        if iface >= len(self.section.interfaces):
            self.tally.add(
                "noiface",
                f"the packet at offset {pos} names interface {iface}, which is not described; "
                "left out",
            )
            return
        interface = self.section.interfaces[iface]
        if interface.link_type != LINKTYPE_USER0:
            self.tally.add(
                f"foreign{interface.link_type}",
                f"packets of interface {iface}, {linktype_name(interface.link_type)}, are not "
                f"motorctl's (the first at offset {pos}); left out",
            )
            return
        payload = body[20 : 20 + caplen]
        at = 20 + caplen + (-caplen % 4)
        head = self.flags_only.unpack_from(body, at) if len(body) - at == 12 else None
        if head is not None and head[:2] == (EPB_FLAGS, 4) and head[3:] == (OPT_END, 0):
            bits, dropped = head[2] & 3, 0  # what motorctl writes: the flags alone, fast
        else:
            opts = _options(body[at:], self.order, pos + 8 + at)
            flags = opts.get(EPB_FLAGS)
            bits = self.u32.unpack(flags[0])[0] & 3 if flags and len(flags[0]) == 4 else 0
            drops = opts.get(EPB_DROPCOUNT)
            dropped = self.u64.unpack(drops[0])[0] if drops and len(drops[0]) == 8 else 0
        if caplen != origlen:
            self.tally.add(
                "cut", f"the packet at offset {pos} was cut to {caplen} of {origlen} bytes"
            )
        direction = _DIRECTIONS[bits]
        if direction is None:
            opts_info = interface.info or CaptureInfo()
            direction = direction_of(payload, opts_info.codec_options())
            if direction is None:
                self.untold += 1
                if self.first_untold < 0:
                    self.first_untold = pos
                return
        num, den = self.resolutions[iface]
        ts = ((hi << 32) | lo) * num // den
        self.cap.records.append(
            Record(ts, direction, payload, dropped, iface, self.cap.packets, pos)
        )


def _parse_pcap(data: bytes, order: str, nanos: bool) -> Capture:
    """A classic pcap file: no directions (told from the bytes where they can be), no
    settings (the defaults), one link."""
    if len(data) < 24:
        raise CaptureError(
            f"a pcap file that ends at offset {len(data)}, inside its 24-byte header"
        )
    network = struct.unpack_from(order + "I", data, 20)[0] & 0x0FFFFFFF
    if network != LINKTYPE_USER0:
        raise CaptureError(
            f"a pcap file of {linktype_name(network)} (its header's link type, offset 20), "
            f"not motorctl's {linktype_name(LINKTYPE_USER0)}"
        )
    cap = Capture(info=None, format="pcap", size=len(data))
    cap.sections.append(Section(0, None, [Interface(0, network, "", None)]))
    opts = CaptureInfo().codec_options()
    untold, first_untold = 0, -1
    pos = 24
    while pos < len(data):
        left = len(data) - pos
        if left < 16:
            cap.truncated_bytes, cap.damaged_at = left, pos
            cap.problems.append(
                f"the file ends inside a record header at offset {pos}: its last {left} "
                "bytes left out"
            )
            break
        sec, frac, incl, _orig = struct.unpack_from(order + "IIII", data, pos)
        if incl > MAX_RECORD:
            cap.damaged_at = pos
            cap.problems.append(
                f"damaged at offset {pos}: a record of {incl} bytes; the {left} bytes from "
                "there on cannot be read"
            )
            break
        if 16 + incl > left:
            cap.truncated_bytes, cap.damaged_at = left, pos
            cap.problems.append(
                f"the file ends inside the record at offset {pos} ({incl} bytes, "
                f"{left - 16} there): its last {left} bytes left out"
            )
            break
        cap.packets += 1
        payload = bytes(data[pos + 16 : pos + 16 + incl])
        direction = direction_of(payload, opts)
        if direction is None:
            untold += 1
            if first_untold < 0:
                first_untold = pos
        else:
            ts = sec * 10**9 + (frac if nanos else frac * 1000)
            cap.records.append(Record(ts, direction, payload, 0, 0, cap.packets, pos))
        pos += 16 + incl
    told = len(cap.records)
    note = (
        "a pcap file (not pcapng): pcap keeps no directions and no settings (read with the "
        f"defaults); {told} of {told + untold} runs' directions were told from their bytes "
        "(whole commands with good checksums: host -> device, whole answers: device -> host)"
    )
    if untold:
        note += (
            f", {untold} could not be (the first at offset {first_untold}) and are left out: "
            "record in pcapng (motorctld --trace and motorctl tap write it) to keep them"
        )
    cap.problems.insert(0, note)
    return cap


def ns_from(origin_wall_ns: int, origin_t: float, t: float) -> int:
    """The timestamp of a record taken at monotonic ``t`` (see the module doc)."""
    return origin_wall_ns + round((t - origin_t) * 1e9)
