"""Pure encoder/decoder for command frames and response frames (PROTOCOL.md sections 1, 3, 5),
and the one decoder of an answer for the command it answers (:func:`decode_answer`).

The commands themselves, their parameters' wire sizes and their answers are the command
table's (:mod:`motorctl.protocol.commands`); this module reads the table and re-exports its
names (``from motorctl.protocol.codec import MoveTo`` keeps working).

Command frame: B0 = code, B1..B8 = parameters then 0x00 padding, B9 = checksum over B0..B8.
Response frame: R0 = ACK, R1..R3 = payload, R4 = checksum over R1..R3 (R0..R3 with
`crc_covers_ack`). Multi-byte values are big-endian; positions are 24-bit two's complement.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final, Literal, NamedTuple

from motorctl.protocol.commands import *  # noqa: F403 (the table's names, re-exported)
from motorctl.protocol.commands import BY_CODE, Command
from motorctl.protocol.crc import SMBUS, Crc8
from motorctl.protocol.spec import POS_MAX as POS_MAX
from motorctl.protocol.spec import POS_MIN as POS_MIN
from motorctl.protocol.spec import WAYPOINTS as WAYPOINTS
from motorctl.protocol.spec import ErrorCode as ErrorCode
from motorctl.protocol.spec import Param, Wire

FRAME_LEN = 10
RESPONSE_LEN = 5
PAYLOAD_LEN = RESPONSE_LEN - 2
_POS_MOD = 1 << 24

#: each command's parameters in wire order: (name, wire, size), by code
_LAYOUT: dict[int, tuple[tuple[str, Wire, int], ...]] = {
    code: tuple((p.name, p.wire, p.size) for p in cls.spec.params) for code, cls in BY_CODE.items()
}
#: and their ranges: (name, wire, size, lowest, highest)
_RANGES: dict[int, tuple[tuple[str, Wire, int, int, int], ...]] = {
    code: tuple((p.name, p.wire, p.size, p.lo, p.hi) for p in cls.spec.params)
    for code, cls in BY_CODE.items()
}


def used_bytes(code: int) -> int:
    """Number of parameter bytes after B0 for `code` (the rest of B1..B8 is padding)."""
    return BY_CODE[code].spec.used_bytes


# --- 24-bit positions -------------------------------------------------------------------


def wrap24(value: int) -> int:
    """Map any int into POS_MIN..POS_MAX as 24-bit two's complement (counter wrap)."""
    return (value - POS_MIN) % _POS_MOD + POS_MIN


def pos24_to_bytes(value: int) -> bytes:
    """Three big-endian bytes of a position; ValueError outside POS_MIN..POS_MAX."""
    if not POS_MIN <= value <= POS_MAX:
        raise ValueError(f"position {value} outside {POS_MIN}..{POS_MAX}")
    return (value % _POS_MOD).to_bytes(3, "big")


def pos24_from_bytes(b: bytes) -> int:
    """Signed position from three big-endian bytes."""
    if len(b) != 3:
        raise ValueError(f"a position is 3 bytes, got {len(b)}")
    return int.from_bytes(b, "big", signed=True)


# --- options and errors -----------------------------------------------------------------


#: the longest silence between two bytes of one frame, by default ([link] frame_gap_ms)
FRAME_GAP_MS: Final = 10.0


@dataclass(frozen=True)
class CodecOptions:
    """Checksum settings. `crc=None` is checksum "none": ignored on input, sent as 0x00."""

    crc: Crc8 | None = SMBUS
    crc_covers_ack: bool = False
    strict_padding: bool = True


FrameErrorReason = Literal["checksum", "unknown", "padding", "length"]


class FrameError(Exception):
    """A complete frame that must be answered with E1 and not executed."""

    def __init__(self, reason: FrameErrorReason, message: str) -> None:
        super().__init__(message)
        self.reason: FrameErrorReason = reason
        self.code: ErrorCode = ErrorCode.INVALID_COMMAND


class ResponseError(Exception):
    """A response frame of the wrong length or with a wrong checksum."""


# --- commands ---------------------------------------------------------------------------


def decode_command(frame: bytes, opts: CodecOptions) -> Command:
    """Parse a 10-byte command frame.

    Checks in order: length (FrameError "length"), checksum over B0..B8 (skipped when
    `opts.crc` is None), command code ("unknown"), padding ("padding", only with
    `strict_padding`). Any non-zero boolean byte reads as True.
    """
    if len(frame) != FRAME_LEN:
        raise FrameError("length", f"command frame is {len(frame)} bytes, not {FRAME_LEN}")
    if opts.crc is not None:
        expected = opts.crc.compute(frame[: FRAME_LEN - 1])
        if frame[FRAME_LEN - 1] != expected:
            raise FrameError(
                "checksum",
                f"checksum 0x{frame[FRAME_LEN - 1]:02X}, expected 0x{expected:02X}",
            )
    cls = BY_CODE.get(frame[0])
    if cls is None:
        raise FrameError("unknown", f"unknown command code 0x{frame[0]:02X}")
    values: dict[str, Any] = {}
    pos = 1
    for name, wire, size in _LAYOUT[cls.code]:
        chunk = frame[pos : pos + size]
        pos += size
        if wire == "bool":
            values[name] = chunk[0] != 0
        elif wire == "s24":
            values[name] = pos24_from_bytes(chunk)
        else:
            values[name] = int.from_bytes(chunk, "big")
    if opts.strict_padding and any(frame[pos : FRAME_LEN - 1]):
        raise FrameError(
            "padding",
            f"non-zero padding in {cls.__name__} frame: {frame[pos : FRAME_LEN - 1].hex()}",
        )
    return cls(**values)


def encode_command(cmd: Command, opts: CodecOptions) -> bytes:
    """Build the 10-byte frame for `cmd`; ValueError naming the field if a value is out of range.

    True is sent as 0x01; padding is 0x00; the checksum is 0x00 when `opts.crc` is None.
    """
    if not isinstance(cmd, Command) or BY_CODE.get(cmd.code) is not type(cmd):
        raise TypeError(f"not a command: {cmd!r}")
    body = bytearray([cmd.code])
    for name, wire, size, low, high in _RANGES[cmd.code]:
        value = getattr(cmd, name)
        if wire == "bool":
            body.append(0x01 if value else 0x00)
            continue
        if not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"{type(cmd).__name__}.{name} = {value!r} outside {low}..{high}")
        if wire == "s24":
            body += pos24_to_bytes(value)
        else:
            body += value.to_bytes(size, "big")
    body += bytes(FRAME_LEN - 1 - len(body))
    body.append(opts.crc.compute(bytes(body)) if opts.crc is not None else 0x00)
    return bytes(body)


def describe(cmd: Command) -> str:
    """Short human text, e.g. "MoveTo(motor=0, dir=up, pos=1200, speed=250, acc=0, dec=0)",
    "DcMove(dir=forward, time_ms=500, hiz=false)"."""
    parts = [f"{p.said}={p.text(getattr(cmd, p.name))}" for p in cmd.spec.params]
    return f"{cmd.spec.name}({', '.join(parts)})"


# --- responses --------------------------------------------------------------------------


@dataclass(frozen=True)
class Response:
    """A response: ACK flag and the 3 payload bytes R1..R3."""

    ack: bool
    payload: bytes

    def __post_init__(self) -> None:
        object.__setattr__(self, "payload", bytes(self.payload))
        if len(self.payload) != PAYLOAD_LEN:
            raise ValueError(
                f"response payload must be {PAYLOAD_LEN} bytes, got {len(self.payload)}"
            )

    @classmethod
    def ok(cls, payload: bytes = b"") -> Response:
        """ACK with up to 3 payload bytes, zero-padded."""
        if len(payload) > PAYLOAD_LEN:
            raise ValueError(f"response payload is at most {PAYLOAD_LEN} bytes, got {len(payload)}")
        return cls(True, bytes(payload) + bytes(PAYLOAD_LEN - len(payload)))

    @classmethod
    def error(cls, code: ErrorCode) -> Response:
        """Error response: R0 = 0x00, R1 = code (one shared instance per code)."""
        known = _ERRORS.get(code)
        return known if known is not None else cls(False, bytes([code, 0, 0]))

    @classmethod
    def boolean(cls, value: bool) -> Response:
        """ACK with R1 = 0x01 / 0x00 (one of two shared instances: answered at every IsReady
        and GetPin, so not built anew each time)."""
        return _TRUE if value else _FALSE

    @classmethod
    def position(cls, pos: int) -> Response:
        """ACK with R1..R3 = position; out-of-range ints wrap modulo 2^24 (the bytes of
        ``pos24_to_bytes(wrap24(pos))``, made at once: answered at every GetAbsPos)."""
        return cls(True, (pos % _POS_MOD).to_bytes(3, "big"))

    @property
    def error_code(self) -> ErrorCode | None:
        """The error code of an error response; None for an ACK or an unknown error byte."""
        if self.ack:
            return None
        try:
            return ErrorCode(self.payload[0])
        except ValueError:
            return None

    @property
    def as_bool(self) -> bool:
        """R1 read as a boolean."""
        return self.payload[0] != 0

    @property
    def as_position(self) -> int:
        """R1..R3 read as a signed 24-bit position."""
        return pos24_from_bytes(self.payload)


class Reading(NamedTuple):
    """An answer read for the command it answers (:func:`decode_answer`): its ``text``
    ("ready", "pos=1200", "waypoint=0", "ok", "E3 Motor not ready"), the error of an error
    answer (``error_byte``: R1; ``error``: its code, None for a code the protocol does not
    have), and the value an ACK carries for its command (``param``: what it is, by the
    table; ``value``: as read, None when it carries none)."""

    ack: bool
    text: str
    error_byte: int | None = None
    error: ErrorCode | None = None
    param: Param | None = None
    value: int | bool | None = None


def decode_answer(cmd: Command | None, resp: Response) -> Reading:
    """``resp`` read as the answer to ``cmd`` (None: a frame that failed its checks), by the
    command table: the one reading of an answer, which the daemon's status, ``motorctl``,
    ``motorctl trace`` and the replay show (the Wireshark dissector is generated from the
    same table and reads it the same way). On the link thread for every answer (the status's
    last frames): no more than a lookup or two."""
    payload = resp.payload
    if not resp.ack:
        byte = payload[0]
        known = _ERROR_READINGS.get(byte)
        return known or Reading(False, f"error 0x{byte:02x} (unknown code)", byte)
    answer = cmd.spec.answer if cmd is not None else None
    p = answer.value if answer is not None else None
    if answer is None or p is None:
        return _OK if payload == _ZERO else Reading(True, f"ok, payload {payload.hex(' ')}")
    value: int | bool
    if p.wire == "bool":
        value = payload[0] != 0
    elif p.wire == "s24":
        value = pos24_from_bytes(payload)
    else:
        value = int.from_bytes(payload[: p.size], "big")
    return Reading(True, answer.text(value), None, None, p, value)


def describe_answer(cmd: Command | None, resp: Response) -> str:
    """Short human text of ``resp`` as the answer to ``cmd`` (None: a frame that failed its
    checks), e.g. "E3 Motor not ready", "pos=1200", "ready", "high", "waypoint=0", "ok"."""
    return decode_answer(cmd, resp).text


# Responses are immutable: the frequent ones exist once.
_TRUE = Response(True, b"\x01\x00\x00")
_FALSE = Response(True, b"\x00\x00\x00")
_ERRORS = {code: Response(False, bytes([code, 0, 0])) for code in ErrorCode}
_ZERO = bytes(PAYLOAD_LEN)
_OK = Reading(True, "ok")
_ERROR_READINGS = {int(c): Reading(False, f"{c.short} {c.label}", int(c), c) for c in ErrorCode}


def _response_crc(r0: int, payload: bytes, opts: CodecOptions) -> int:
    if opts.crc is None:
        return 0x00
    covered = bytes([r0]) + payload if opts.crc_covers_ack else payload
    return opts.crc.compute(covered)


def encode_response(resp: Response, opts: CodecOptions) -> bytes:
    """Build the 5-byte response frame."""
    r0 = 0x01 if resp.ack else 0x00
    return bytes([r0, *resp.payload, _response_crc(r0, resp.payload, opts)])


def decode_response(data: bytes, opts: CodecOptions) -> Response:
    """Parse a 5-byte response frame; any non-zero R0 reads as ACK.

    ResponseError on a wrong length or checksum (the checksum is not checked with crc None).
    """
    if len(data) != RESPONSE_LEN:
        raise ResponseError(f"response is {len(data)} bytes, not {RESPONSE_LEN}")
    payload = bytes(data[1:4])
    if opts.crc is not None:
        expected = _response_crc(data[0], payload, opts)
        if data[4] != expected:
            raise ResponseError(f"response checksum 0x{data[4]:02X}, expected 0x{expected:02X}")
    return Response(data[0] != 0, payload)
