"""Pure encoder/decoder for command frames and response frames (PROTOCOL.md sections 1, 3, 5).

Over 500 lines on purpose: the whole wire format in one place, both directions, so
that the encoder and the decoder of a frame sit side by side; each command is a small
dataclass.

Command frame: B0 = code, B1..B8 = parameters then 0x00 padding, B9 = checksum over B0..B8.
Response frame: R0 = ACK, R1..R3 = payload, R4 = checksum over R1..R3 (R0..R3 with
`crc_covers_ack`). Multi-byte values are big-endian; positions are 24-bit two's complement.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, ClassVar, Literal, TypeAlias

from motorctl.protocol.crc import SMBUS, Crc8

FRAME_LEN = 10
RESPONSE_LEN = 5
PAYLOAD_LEN = RESPONSE_LEN - 2
POS_MIN = -8_388_608
POS_MAX = 8_388_607
_POS_MOD = 1 << 24


class ErrorCode(IntEnum):
    """Error codes sent in R1 of an error response."""

    FULL_BUFFER = 0xE0
    INVALID_COMMAND = 0xE1
    INVALID_ADDRESS = 0xE2
    MOTOR_NOT_READY = 0xE3
    MOTOR_ERROR = 0xE4
    FULL_WAYPOINT_BUFFER = 0xE5
    INVALID_WAYPOINT = 0xE6

    @property
    def label(self) -> str:
        """The name the original specification uses."""
        return _ERROR_LABELS[self]

    @property
    def short(self) -> str:
        """Short form E0..E6."""
        return f"E{self.value - 0xE0}"


_ERROR_LABELS: dict[ErrorCode, str] = {
    ErrorCode.FULL_BUFFER: "Full Buffer",
    ErrorCode.INVALID_COMMAND: "Invalid Command",
    ErrorCode.INVALID_ADDRESS: "Invalid Address",
    ErrorCode.MOTOR_NOT_READY: "Motor not ready",
    ErrorCode.MOTOR_ERROR: "Motor Error",
    ErrorCode.FULL_WAYPOINT_BUFFER: "Full Way Point Buffer",
    ErrorCode.INVALID_WAYPOINT: "Invalid Way Point",
}


class CommandCode(IntEnum):
    """Command codes (B0)."""

    INIT_MOVE = 0x00
    MOVE_TO = 0x01
    WAIT_MOVED = 0x02
    IS_READY = 0x03
    MOVE = 0x04
    STOP_MOVE = 0x05
    GET_ABS_POS = 0x06
    SET_PIN = 0x07
    GET_PIN = 0x08
    CONFIG_PIN = 0x09
    SAVE_HOME = 0x0A
    GO_HOME = 0x0B
    SAVE_WAY_POINT = 0x0C
    MOVE_TO_WAY_POINT = 0x0D
    DC_MOVE = 0x0E


# Field order in every command dataclass is the wire order of its parameters (B1 onwards).


@dataclass(frozen=True)
class InitMove:
    """0x00: run in `direction` to the end stop, then set the position to 0."""

    code: ClassVar[CommandCode] = CommandCode.INIT_MOVE
    motor: int
    direction: bool
    speed: int
    acc: int
    dec: int


@dataclass(frozen=True)
class MoveTo:
    """0x01: move to an absolute position (signed 24-bit)."""

    code: ClassVar[CommandCode] = CommandCode.MOVE_TO
    motor: int
    direction: bool
    position: int
    speed: int
    acc: int
    dec: int


@dataclass(frozen=True)
class WaitMoved:
    """0x02: answer when the motor is idle, or E3 after `timeout_ms`."""

    code: ClassVar[CommandCode] = CommandCode.WAIT_MOVED
    motor: int
    timeout_ms: int


@dataclass(frozen=True)
class IsReady:
    """0x03: TRUE when the motor is idle with an empty queue."""

    code: ClassVar[CommandCode] = CommandCode.IS_READY
    motor: int


@dataclass(frozen=True)
class Move:
    """0x04: run continuously until stopped."""

    code: ClassVar[CommandCode] = CommandCode.MOVE
    motor: int
    direction: bool
    speed: int
    acc: int
    dec: int


@dataclass(frozen=True)
class StopMove:
    """0x05: stop at once (hard) or along the deceleration ramp."""

    code: ClassVar[CommandCode] = CommandCode.STOP_MOVE
    motor: int
    hard: bool


@dataclass(frozen=True)
class GetAbsPos:
    """0x06: current position."""

    code: ClassVar[CommandCode] = CommandCode.GET_ABS_POS
    motor: int


@dataclass(frozen=True)
class SetPin:
    """0x07: drive an output pin."""

    code: ClassVar[CommandCode] = CommandCode.SET_PIN
    pin: int
    high: bool


@dataclass(frozen=True)
class GetPin:
    """0x08: read a pin."""

    code: ClassVar[CommandCode] = CommandCode.GET_PIN
    pin: int


@dataclass(frozen=True)
class ConfigPin:
    """0x09: switch a pin between input and output."""

    code: ClassVar[CommandCode] = CommandCode.CONFIG_PIN
    pin: int
    output: bool


@dataclass(frozen=True)
class SaveHome:
    """0x0A: store the current position as home."""

    code: ClassVar[CommandCode] = CommandCode.SAVE_HOME
    motor: int


@dataclass(frozen=True)
class GoHome:
    """0x0B: move to the stored home position."""

    code: ClassVar[CommandCode] = CommandCode.GO_HOME
    motor: int


@dataclass(frozen=True)
class SaveWayPoint:
    """0x0C: store the current position as the next waypoint."""

    code: ClassVar[CommandCode] = CommandCode.SAVE_WAY_POINT
    motor: int


@dataclass(frozen=True)
class MoveToWayPoint:
    """0x0D: move to a stored waypoint."""

    code: ClassVar[CommandCode] = CommandCode.MOVE_TO_WAY_POINT
    motor: int
    waypoint: int
    speed: int
    acc: int
    dec: int


@dataclass(frozen=True)
class DcMove:
    """0x0E: run the DC motor for `time_ms`, then coast (hiz) or brake."""

    code: ClassVar[CommandCode] = CommandCode.DC_MOVE
    direction: bool
    time_ms: int
    hiz: bool


Command: TypeAlias = (
    InitMove
    | MoveTo
    | WaitMoved
    | IsReady
    | Move
    | StopMove
    | GetAbsPos
    | SetPin
    | GetPin
    | ConfigPin
    | SaveHome
    | GoHome
    | SaveWayPoint
    | MoveToWayPoint
    | DcMove
)

COMMAND_TYPES: tuple[type[Command], ...] = (
    InitMove,
    MoveTo,
    WaitMoved,
    IsReady,
    Move,
    StopMove,
    GetAbsPos,
    SetPin,
    GetPin,
    ConfigPin,
    SaveHome,
    GoHome,
    SaveWayPoint,
    MoveToWayPoint,
    DcMove,
)
"""All command classes, in code order."""

_BY_CODE: dict[int, type[Command]] = {cls.code: cls for cls in COMMAND_TYPES}

_Kind = Literal["u8", "bool", "u16", "s24"]
_SIZE: dict[_Kind, int] = {"u8": 1, "bool": 1, "u16": 2, "s24": 3}
_FIELD_KIND: dict[str, _Kind] = {
    "motor": "u8",
    "pin": "u8",
    "speed": "u8",
    "acc": "u8",
    "dec": "u8",
    "waypoint": "u8",
    "direction": "bool",
    "hard": "bool",
    "high": "bool",
    "output": "bool",
    "hiz": "bool",
    "timeout_ms": "u16",
    "time_ms": "u16",
    "position": "s24",
}


def _layout(cls: type[Command]) -> tuple[tuple[str, _Kind], ...]:
    return tuple((f.name, _FIELD_KIND[f.name]) for f in dataclasses.fields(cls))


_LAYOUT: dict[int, tuple[tuple[str, _Kind], ...]] = {
    cls.code: _layout(cls) for cls in COMMAND_TYPES
}


def used_bytes(code: CommandCode) -> int:
    """Number of parameter bytes after B0 for `code` (the rest of B1..B8 is padding)."""
    return sum(_SIZE[kind] for _, kind in _LAYOUT[code])


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
    cls = _BY_CODE.get(frame[0])
    if cls is None:
        raise FrameError("unknown", f"unknown command code 0x{frame[0]:02X}")
    values: dict[str, Any] = {}
    pos = 1
    for name, kind in _LAYOUT[cls.code]:
        size = _SIZE[kind]
        chunk = frame[pos : pos + size]
        pos += size
        if kind == "bool":
            values[name] = chunk[0] != 0
        elif kind == "s24":
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
    if not isinstance(cmd, COMMAND_TYPES):
        raise TypeError(f"not a command: {cmd!r}")
    body = bytearray([cmd.code])
    for name, kind in _LAYOUT[cmd.code]:
        value = getattr(cmd, name)
        if kind == "bool":
            body.append(0x01 if value else 0x00)
            continue
        if kind == "s24":
            low, high = POS_MIN, POS_MAX
        else:
            low, high = 0, (1 << (8 * _SIZE[kind])) - 1
        if not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"{type(cmd).__name__}.{name} = {value!r} outside {low}..{high}")
        if kind == "s24":
            body += pos24_to_bytes(value)
        else:
            body += value.to_bytes(_SIZE[kind], "big")
    body += bytes(FRAME_LEN - 1 - len(body))
    body.append(opts.crc.compute(bytes(body)) if opts.crc is not None else 0x00)
    return bytes(body)


_SHORT_NAMES = {"direction": "dir", "position": "pos"}


def describe(cmd: Command) -> str:
    """Short human text, e.g. "MoveTo(motor=0, dir=up, pos=1200, speed=250, acc=0, dec=0)",
    "DcMove(dir=forward, time_ms=500, hiz=false)"."""
    parts: list[str] = []
    for name, kind in _LAYOUT[cmd.code]:
        value = getattr(cmd, name)
        if name == "direction" and cmd.code is CommandCode.DC_MOVE:
            text = "forward" if value else "reverse"  # as the CLI says it (motorctl dc)
        elif name == "direction":
            text = "up" if value else "down"
        elif kind == "bool":
            text = "true" if value else "false"
        else:
            text = str(value)
        parts.append(f"{_SHORT_NAMES.get(name, name)}={text}")
    return f"{type(cmd).__name__}({', '.join(parts)})"


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
        """ACK with R1..R3 = position; out-of-range ints wrap modulo 2^24."""
        return cls.ok(pos24_to_bytes(wrap24(pos)))

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


def describe_answer(cmd: Command | None, resp: Response) -> str:
    """Short human text of ``resp`` as the answer to ``cmd`` (None: a frame that failed its
    checks), e.g. "E3 Motor not ready", "pos=1200", "ready", "high", "waypoint=0", "ok"."""
    if not resp.ack:
        code = resp.error_code
        return (
            f"{code.short} {code.label}" if code is not None else f"error 0x{resp.payload[0]:02X}"
        )
    if isinstance(cmd, GetAbsPos):
        return f"pos={resp.as_position}"
    if isinstance(cmd, IsReady):
        return "ready" if resp.as_bool else "busy"
    if isinstance(cmd, GetPin):
        return "high" if resp.as_bool else "low"
    if isinstance(cmd, SaveWayPoint):
        return f"waypoint={resp.payload[0]}"
    return "ok"


# Responses are immutable: the frequent ones exist once.
_TRUE = Response(True, b"\x01\x00\x00")
_FALSE = Response(True, b"\x00\x00\x00")
_ERRORS = {code: Response(False, bytes([code, 0, 0])) for code in ErrorCode}


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
