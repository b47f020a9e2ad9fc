"""The trace format's facts (the package's doc, docs/trace.md): its block and option codes,
the settings a reader needs (:class:`CaptureInfo`, the section comment), one byte run
(:class:`Record`) and its direction, and :class:`CaptureError`.

Pure: constants and frozen records, no state; used on any thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from motorctl.protocol.codec import FRAME_GAP_MS, CodecOptions
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
    crc_covers_ack: bool = CodecOptions.crc_covers_ack
    strict_padding: bool = CodecOptions.strict_padding
    frame_gap_ms: float = FRAME_GAP_MS
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
