"""Tests for motorctl.protocol.codec."""

from __future__ import annotations

import dataclasses
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from motorctl.protocol.codec import (
    FRAME_LEN,
    MOTION_COMMANDS,
    POS_MAX,
    POS_MIN,
    RESPONSE_LEN,
    WAYPOINTS,
    CodecOptions,
    Command,
    CommandCode,
    ConfigPin,
    DcMove,
    ErrorCode,
    FrameError,
    GetAbsPos,
    GetPin,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    Response,
    ResponseError,
    SaveHome,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
    decode_answer,
    decode_command,
    decode_response,
    describe,
    describe_answer,
    encode_command,
    encode_response,
    pos24_from_bytes,
    pos24_to_bytes,
    used_bytes,
    wrap24,
)
from motorctl.protocol.crc import crc8_by_name
from tests.support import REPO
from tests.support.frames import raw_frame, ref_crc8

OPTS = CodecOptions()
NO_CRC = CodecOptions(crc=None)
LOOSE = CodecOptions(strict_padding=False)


def maxim(data: bytes) -> int:
    """Bitwise CRC-8/MAXIM-DOW (poly 0x31 reflected = 0x8C, init 0, xorout 0)."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8C if crc & 1 else crc >> 1
    return crc


def with_crc(body: bytes) -> bytes:
    return body + bytes([ref_crc8(body)])


VECTORS: list[tuple[Command, str]] = [
    (InitMove(motor=1, direction=True, speed=0x10, acc=0x20, dec=0x30), "00 01 01 10 20 30"),
    (InitMove(motor=0, direction=False, speed=0, acc=0, dec=0), "00"),
    (
        MoveTo(motor=2, direction=False, position=1200, speed=250, acc=3, dec=4),
        "01 02 00 00 04 B0 FA 03 04",
    ),
    (
        MoveTo(motor=0xFF, direction=True, position=-2, speed=1, acc=2, dec=3),
        "01 FF 01 FF FF FE 01 02 03",
    ),
    (
        MoveTo(motor=0, direction=True, position=POS_MIN, speed=0, acc=0, dec=0),
        "01 00 01 80 00 00",
    ),
    (
        MoveTo(motor=0, direction=True, position=POS_MAX, speed=0, acc=0, dec=0),
        "01 00 01 7F FF FF",
    ),
    (WaitMoved(motor=3, timeout_ms=0x1234), "02 03 12 34"),
    (WaitMoved(motor=0, timeout_ms=65535), "02 00 FF FF"),
    (IsReady(motor=0), "03"),
    (IsReady(motor=9), "03 09"),
    (Move(motor=3, direction=True, speed=0xFF, acc=1, dec=2), "04 03 01 FF 01 02"),
    (StopMove(motor=1, hard=True), "05 01 01"),
    (StopMove(motor=1, hard=False), "05 01 00"),
    (GetAbsPos(motor=7), "06 07"),
    (SetPin(pin=5, high=True), "07 05 01"),
    (GetPin(pin=9), "08 09"),
    (ConfigPin(pin=4, output=False), "09 04 00"),
    (ConfigPin(pin=4, output=True), "09 04 01"),
    (SaveHome(motor=1), "0A 01"),
    (GoHome(motor=2), "0B 02"),
    (SaveWayPoint(motor=3), "0C 03"),
    (MoveToWayPoint(motor=1, waypoint=7, speed=100, acc=10, dec=20), "0D 01 07 64 0A 14"),
    (DcMove(direction=True, time_ms=0xABCD, hiz=False), "0E 01 AB CD 00"),
    (DcMove(direction=False, time_ms=1, hiz=True), "0E 00 00 01 01"),
]

ALL_CLASSES: set[type[Command]] = {
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
}

USED: dict[type[Command], int] = {
    InitMove: 5,
    MoveTo: 8,
    WaitMoved: 3,
    IsReady: 1,
    Move: 5,
    StopMove: 2,
    GetAbsPos: 1,
    SetPin: 2,
    GetPin: 1,
    ConfigPin: 2,
    SaveHome: 1,
    GoHome: 1,
    SaveWayPoint: 1,
    MoveToWayPoint: 5,
    DcMove: 4,
}


def test_vectors_cover_every_command() -> None:
    assert {type(cmd) for cmd, _ in VECTORS} == ALL_CLASSES
    assert {cls.code for cls in ALL_CLASSES} == set(CommandCode)


def test_protocol_example() -> None:
    example = bytes.fromhex("03 00 00 00 00 00 00 00 00 8B")
    assert ref_crc8(example[:9]) == 0x8B  # the reference CRC agrees with PROTOCOL.md
    assert encode_command(IsReady(0), OPTS) == example
    assert decode_command(example, OPTS) == IsReady(0)


@pytest.mark.parametrize(("cmd", "body"), VECTORS, ids=lambda v: str(v))
def test_vector_encode(cmd: Command, body: str) -> None:
    assert encode_command(cmd, OPTS) == raw_frame(body)


@pytest.mark.parametrize(("cmd", "body"), VECTORS, ids=lambda v: str(v))
def test_vector_decode(cmd: Command, body: str) -> None:
    decoded = decode_command(raw_frame(body), OPTS)
    assert decoded == cmd
    assert type(decoded) is type(cmd)


def test_used_bytes() -> None:
    for cls, n in USED.items():
        assert used_bytes(cls.code) == n


def test_true_bytes_any_nonzero_decode_true() -> None:
    for value in (0x01, 0x02, 0x80, 0xFF):
        assert decode_command(raw_frame(f"05 01 {value:02X}"), OPTS) == StopMove(1, True)
        assert decode_command(raw_frame(f"0E {value:02X} 00 05 {value:02X}"), OPTS) == DcMove(
            True, 5, True
        )
        cmd = decode_command(raw_frame(f"01 00 {value:02X} 00 00 01"), OPTS)
        assert isinstance(cmd, MoveTo)
        assert cmd.direction is True
    decoded = decode_command(raw_frame("07 03 00"), OPTS)
    assert isinstance(decoded, SetPin)
    assert decoded.high is False


def test_true_encodes_as_one() -> None:
    assert encode_command(SetPin(1, True), OPTS)[2] == 0x01


# --- frame errors --------------------------------------------------------------------------


def test_bad_checksum() -> None:
    good = raw_frame("03")
    bad = good[:9] + bytes([good[9] ^ 0x01])
    with pytest.raises(FrameError) as info:
        decode_command(bad, OPTS)
    assert info.value.reason == "checksum"
    assert info.value.code is ErrorCode.INVALID_COMMAND


def test_unknown_code() -> None:
    for code in (0x0F, 0x10, 0x7F, 0xFF):
        with pytest.raises(FrameError) as info:
            decode_command(raw_frame(f"{code:02X} 00"), OPTS)
        assert info.value.reason == "unknown"
        assert info.value.code is ErrorCode.INVALID_COMMAND


def test_checksum_checked_before_code() -> None:
    body = bytes.fromhex("FF 00 00 00 00 00 00 00 00")
    with pytest.raises(FrameError) as info:
        decode_command(body + bytes([ref_crc8(body) ^ 0xFF]), OPTS)
    assert info.value.reason == "checksum"


def test_code_checked_before_padding() -> None:
    with pytest.raises(FrameError) as info:
        decode_command(raw_frame("FF 01 01 01 01 01 01 01 01"), OPTS)
    assert info.value.reason == "unknown"


@pytest.mark.parametrize("length", [0, 1, 9, 11, 20])
def test_wrong_length(length: int) -> None:
    with pytest.raises(FrameError) as info:
        decode_command(bytes(length), OPTS)
    assert info.value.reason == "length"


@pytest.mark.parametrize(("cmd", "body"), VECTORS, ids=lambda v: str(v))
def test_strict_padding(cmd: Command, body: str) -> None:
    first_pad = 1 + USED[type(cmd)]
    for index in range(first_pad, 9):
        raw = bytearray(bytes.fromhex(body) + bytes(9 - len(bytes.fromhex(body))))
        raw[index] = 0x5A
        padded = with_crc(bytes(raw))
        with pytest.raises(FrameError) as info:
            decode_command(padded, OPTS)
        assert info.value.reason == "padding"
        assert decode_command(padded, LOOSE) == cmd


def test_strict_padding_leaves_parameters_alone() -> None:
    # B8 is a parameter of MoveTo, so a non-zero B8 is not padding.
    expected = MoveTo(0, False, 0, 0, 0, 255)
    assert decode_command(raw_frame("01 00 00 00 00 00 00 00 FF"), OPTS) == expected


def test_checksum_none_ignores_input_and_sends_zero() -> None:
    encoded = encode_command(IsReady(4), NO_CRC)
    assert encoded == bytes.fromhex("03 04 00 00 00 00 00 00 00 00")
    for checksum in (0x00, 0x8B, 0xFF):
        assert decode_command(encoded[:9] + bytes([checksum]), NO_CRC) == IsReady(4)
    with pytest.raises(FrameError) as info:
        decode_command(bytes.fromhex("20 00 00 00 00 00 00 00 00 00"), NO_CRC)
    assert info.value.reason == "unknown"
    with pytest.raises(FrameError) as info:
        decode_command(bytes.fromhex("03 00 01 00 00 00 00 00 00 00"), NO_CRC)
    assert info.value.reason == "padding"


def test_other_crc_variant_end_to_end() -> None:
    opts = CodecOptions(crc=crc8_by_name("CRC-8/MAXIM"))
    cmd = MoveTo(motor=1, direction=True, position=-1200, speed=9, acc=8, dec=7)
    encoded = encode_command(cmd, opts)
    assert encoded[9] == maxim(encoded[:9])
    assert encoded[9] != ref_crc8(encoded[:9])
    assert decode_command(encoded, opts) == cmd
    with pytest.raises(FrameError):
        decode_command(encoded, OPTS)
    resp = Response.position(-1200)
    wire = encode_response(resp, opts)
    assert wire[4] == maxim(wire[1:4])
    assert decode_response(wire, opts) == resp


# --- encode validation ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("cmd", "field"),
    [
        (IsReady(256), "motor"),
        (IsReady(-1), "motor"),
        (MoveTo(0, True, POS_MAX + 1, 0, 0, 0), "position"),
        (MoveTo(0, True, POS_MIN - 1, 0, 0, 0), "position"),
        (WaitMoved(0, 65536), "timeout_ms"),
        (WaitMoved(0, -1), "timeout_ms"),
        (Move(0, True, 256, 0, 0), "speed"),
        (InitMove(0, True, 0, 300, 0), "acc"),
        (MoveToWayPoint(0, 0, 0, 0, -5), "dec"),
        (MoveToWayPoint(0, 256, 0, 0, 0), "waypoint"),
        (SetPin(1000, True), "pin"),
        (DcMove(True, 70000, False), "time_ms"),
    ],
)
def test_encode_rejects_out_of_range(cmd: Command, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        encode_command(cmd, OPTS)


def test_encode_rejects_non_command() -> None:
    with pytest.raises(TypeError):
        encode_command("IsReady", OPTS)  # type: ignore[arg-type]


# --- hypothesis ----------------------------------------------------------------------------

u8 = st.integers(0, 255)
u16 = st.integers(0, 65535)
pos = st.integers(POS_MIN, POS_MAX)
flag = st.booleans()

COMMANDS: st.SearchStrategy[Command] = st.one_of(
    st.builds(InitMove, motor=u8, direction=flag, speed=u8, acc=u8, dec=u8),
    st.builds(MoveTo, motor=u8, direction=flag, position=pos, speed=u8, acc=u8, dec=u8),
    st.builds(WaitMoved, motor=u8, timeout_ms=u16),
    st.builds(IsReady, motor=u8),
    st.builds(Move, motor=u8, direction=flag, speed=u8, acc=u8, dec=u8),
    st.builds(StopMove, motor=u8, hard=flag),
    st.builds(GetAbsPos, motor=u8),
    st.builds(SetPin, pin=u8, high=flag),
    st.builds(GetPin, pin=u8),
    st.builds(ConfigPin, pin=u8, output=flag),
    st.builds(SaveHome, motor=u8),
    st.builds(GoHome, motor=u8),
    st.builds(SaveWayPoint, motor=u8),
    st.builds(MoveToWayPoint, motor=u8, waypoint=u8, speed=u8, acc=u8, dec=u8),
    st.builds(DcMove, direction=flag, time_ms=u16, hiz=flag),
)

ALL_OPTIONS = st.builds(
    CodecOptions,
    crc=st.sampled_from([crc8_by_name("CRC-8/SMBUS"), crc8_by_name("CRC-8/ROHC"), None]),
    crc_covers_ack=flag,
    strict_padding=flag,
)


@given(COMMANDS)
def test_roundtrip_smbus(cmd: Command) -> None:
    encoded = encode_command(cmd, OPTS)
    assert len(encoded) == FRAME_LEN
    assert encoded[0] == cmd.code
    assert encoded[9] == ref_crc8(encoded[:9])
    assert not any(encoded[1 + USED[type(cmd)] : 9])
    assert decode_command(encoded, OPTS) == cmd


@given(COMMANDS, ALL_OPTIONS)
def test_roundtrip_any_options(cmd: Command, opts: CodecOptions) -> None:
    assert decode_command(encode_command(cmd, opts), opts) == cmd


@given(COMMANDS, st.integers(0, 8), st.integers(1, 255))
def test_any_single_byte_corruption_is_caught(cmd: Command, index: int, flip: int) -> None:
    encoded = bytearray(encode_command(cmd, OPTS))
    encoded[index] ^= flip
    with pytest.raises(FrameError) as info:
        decode_command(bytes(encoded), OPTS)
    assert info.value.reason == "checksum"


def _decode_or_frame_error(data: bytes, opts: CodecOptions) -> None:
    try:
        result = decode_command(data, opts)
    except FrameError as exc:
        assert exc.reason in ("checksum", "unknown", "padding", "length")
        assert exc.code is ErrorCode.INVALID_COMMAND
    else:
        assert type(result) in ALL_CLASSES
        assert decode_command(encode_command(result, opts), opts) == result


@given(st.binary(min_size=FRAME_LEN, max_size=FRAME_LEN), ALL_OPTIONS)
def test_random_frames_decode_or_frame_error(data: bytes, opts: CodecOptions) -> None:
    _decode_or_frame_error(data, opts)


@given(st.binary(min_size=9, max_size=9), flag)
def test_random_frames_with_valid_crc(body: bytes, strict: bool) -> None:
    _decode_or_frame_error(with_crc(body), CodecOptions(strict_padding=strict))


@given(st.binary(max_size=30))
def test_random_lengths_never_escape_frame_error(data: bytes) -> None:
    _decode_or_frame_error(data, OPTS)


# --- responses -----------------------------------------------------------------------------


def test_ack_response() -> None:
    resp = Response.ok()
    assert resp == Response(True, b"\x00\x00\x00")
    assert encode_response(resp, OPTS) == bytes([1, 0, 0, 0, ref_crc8(b"\x00\x00\x00")])
    assert resp.error_code is None
    assert Response.ok(b"\x07") == Response(True, b"\x07\x00\x00")


def test_ok_payload_too_long() -> None:
    with pytest.raises(ValueError):
        Response.ok(b"\x01\x02\x03\x04")
    with pytest.raises(ValueError):
        Response(True, b"\x01")


@pytest.mark.parametrize("code", list(ErrorCode))
def test_error_response(code: ErrorCode) -> None:
    resp = Response.error(code)
    assert resp.ack is False
    assert resp.payload == bytes([code, 0, 0])
    assert resp.error_code is code
    wire = encode_response(resp, OPTS)
    assert wire == bytes([0, code, 0, 0, ref_crc8(bytes([code, 0, 0]))])
    assert decode_response(wire, OPTS) == resp


def test_unknown_error_byte() -> None:
    resp = decode_response(bytes([0x00, 0x42, 0x00, 0x00, ref_crc8(b"\x42\x00\x00")]), OPTS)
    assert resp.ack is False
    assert resp.error_code is None
    assert resp.payload[0] == 0x42


def test_boolean_response() -> None:
    assert Response.boolean(True).payload == b"\x01\x00\x00"
    assert Response.boolean(False).payload == b"\x00\x00\x00"
    assert Response.boolean(True).as_bool is True
    assert Response.boolean(False).as_bool is False
    assert Response(True, b"\xff\x00\x00").as_bool is True


@pytest.mark.parametrize(
    ("value", "wire"),
    [(-1, "FFFFFF"), (0, "000000"), (POS_MIN, "800000"), (POS_MAX, "7FFFFF"), (1200, "0004B0")],
)
def test_position_response(value: int, wire: str) -> None:
    resp = Response.position(value)
    assert resp.ack is True
    assert resp.payload == bytes.fromhex(wire)
    assert resp.as_position == value
    encoded = encode_response(resp, OPTS)
    assert encoded == bytes([1]) + bytes.fromhex(wire) + bytes([ref_crc8(bytes.fromhex(wire))])
    assert decode_response(encoded, OPTS).as_position == value


def test_position_response_wraps() -> None:
    assert Response.position(POS_MAX + 1).as_position == POS_MIN
    assert Response.position(POS_MIN - 1).as_position == POS_MAX
    assert Response.position(1 << 24).as_position == 0
    assert Response.position((1 << 24) + 5).as_position == 5


@given(st.integers(min_value=-(1 << 40), max_value=1 << 40))
def test_a_position_response_is_its_wrapped_positions_bytes(value: int) -> None:
    """Any int: the payload of its 24-bit wrap (what ``Response.position`` makes at once)."""
    assert Response.position(value) == Response.ok(pos24_to_bytes(wrap24(value)))
    assert Response.position(value).as_position == wrap24(value)


def test_crc_covers_ack() -> None:
    covers = CodecOptions(crc_covers_ack=True)
    for resp in (Response.ok(), Response.boolean(True), Response.error(ErrorCode.MOTOR_ERROR)):
        r0 = 1 if resp.ack else 0
        wire = encode_response(resp, covers)
        assert wire[4] == ref_crc8(bytes([r0]) + resp.payload)
        assert wire[:4] == encode_response(resp, OPTS)[:4]
        assert decode_response(wire, covers) == resp
    # Only the ACK byte differs in coverage, so the two settings disagree on the CRC.
    wire = encode_response(Response.ok(), covers)
    assert wire[4] != encode_response(Response.ok(), OPTS)[4]
    with pytest.raises(ResponseError):
        decode_response(wire, OPTS)


def test_response_checksum_none() -> None:
    wire = encode_response(Response.position(-1), NO_CRC)
    assert wire == bytes.fromhex("01 FF FF FF 00")
    assert decode_response(bytes.fromhex("01 FF FF FF 5A"), NO_CRC) == Response.position(-1)


def test_response_errors() -> None:
    good = encode_response(Response.boolean(True), OPTS)
    with pytest.raises(ResponseError):
        decode_response(good[:4] + bytes([good[4] ^ 0x10]), OPTS)
    for length in (0, 4, 6):
        with pytest.raises(ResponseError):
            decode_response(bytes(length), OPTS)


def test_response_nonzero_ack_reads_true() -> None:
    payload = b"\x00\x00\x00"
    assert decode_response(bytes([0x7F, *payload, ref_crc8(payload)]), OPTS).ack is True


@given(st.booleans(), st.binary(min_size=3, max_size=3), ALL_OPTIONS)
def test_response_roundtrip(ack: bool, payload: bytes, opts: CodecOptions) -> None:
    resp = Response(ack, payload)
    wire = encode_response(resp, opts)
    assert len(wire) == RESPONSE_LEN
    assert decode_response(wire, opts) == resp


@given(st.binary(min_size=RESPONSE_LEN, max_size=RESPONSE_LEN), ALL_OPTIONS)
def test_random_responses_decode_or_response_error(data: bytes, opts: CodecOptions) -> None:
    try:
        resp = decode_response(data, opts)
    except ResponseError:
        assert opts.crc is not None
    else:
        assert resp.payload == data[1:4]


# --- positions and enums -------------------------------------------------------------------


@given(st.integers(-(1 << 40), 1 << 40))
def test_wrap24(value: int) -> None:
    wrapped = wrap24(value)
    assert POS_MIN <= wrapped <= POS_MAX
    assert (wrapped - value) % (1 << 24) == 0


@given(pos)
def test_pos24_roundtrip(value: int) -> None:
    assert wrap24(value) == value
    raw = pos24_to_bytes(value)
    assert len(raw) == 3
    assert pos24_from_bytes(raw) == value
    assert int.from_bytes(raw, "big") == value % (1 << 24)


def test_pos24_bounds() -> None:
    with pytest.raises(ValueError):
        pos24_to_bytes(POS_MAX + 1)
    with pytest.raises(ValueError):
        pos24_to_bytes(POS_MIN - 1)
    with pytest.raises(ValueError):
        pos24_from_bytes(b"\x00\x00")


def test_error_code_labels() -> None:
    expected = {
        0xE0: ("Full Buffer", "E0"),
        0xE1: ("Invalid Command", "E1"),
        0xE2: ("Invalid Address", "E2"),
        0xE3: ("Motor not ready", "E3"),
        0xE4: ("Motor Error", "E4"),
        0xE5: ("Full Way Point Buffer", "E5"),
        0xE6: ("Invalid Way Point", "E6"),
    }
    assert {int(c) for c in ErrorCode} == set(expected)
    for code in ErrorCode:
        assert (code.label, code.short) == expected[code]


def test_describe() -> None:
    assert (
        describe(MoveTo(motor=0, direction=True, position=1200, speed=250, acc=0, dec=0))
        == "MoveTo(motor=0, dir=up, pos=1200, speed=250, acc=0, dec=0)"
    )
    assert describe(StopMove(motor=2, hard=False)) == "StopMove(motor=2, hard=false)"
    assert describe(DcMove(False, 100, True)) == "DcMove(dir=reverse, time_ms=100, hiz=true)"


def test_command_field_names() -> None:
    names = {cls: tuple(f.name for f in dataclasses.fields(cls)) for cls in ALL_CLASSES}
    assert names[MoveTo] == ("motor", "direction", "position", "speed", "acc", "dec")
    assert names[WaitMoved] == ("motor", "timeout_ms")
    assert names[MoveToWayPoint] == ("motor", "waypoint", "speed", "acc", "dec")
    assert names[DcMove] == ("direction", "time_ms", "hiz")


#: The protocol's facts, owned here and imported by every room that may (issue 23, "Written
#: once"): how each would look written again.
FACTS = {
    "the 24-bit position range": re.compile(
        r"^\s*(?:POS_MIN|POS_MAX)\s*[:=]|\b8_?388_?60[78]\b"
        r"|-\(1 << 23\)|\(1 << 23\) - 1\b|2 \*\* 23",
        re.M,
    ),
    "the waypoint table's size": re.compile(
        r"^\s*\w*WAYPOINTS\s*[:=]|max_waypoints\s*:\s*int\s*=\s*\d|integer\(\s*255,\s*1,\s*255",
        re.M,
    ),
    "the motion commands": re.compile(
        r"\(\s*InitMove,\s*MoveTo,\s*Move,\s*GoHome,\s*MoveToWayPoint\s*\)|^\s*MOTION\w*\s*=", re.M
    ),
}
#: where a fact is written again on purpose: hal/ may not import protocol/ (the rooms' order),
#: so the mock's end-stop range is written out there and checked against POS_MIN/POS_MAX
#: (tests/daemon/test_config.py)
AGAIN = {("hal/backends/mock/config.py", "the 24-bit position range")}


def test_the_protocols_facts_are_declared_in_protocol_only() -> None:
    again = set()
    for room in ("client", "daemon", "motion", "hal"):
        for path in sorted((REPO / room).rglob("*.py")):
            source = path.read_text(encoding="utf-8")
            where = path.relative_to(REPO).as_posix()
            again |= {(where, fact) for fact, pattern in FACTS.items() if pattern.search(source)}
    assert again == AGAIN
    assert WAYPOINTS == 255 and (POS_MIN, POS_MAX) == (-(1 << 23), (1 << 23) - 1)
    assert (InitMove, MoveTo, Move, GoHome, MoveToWayPoint) == MOTION_COMMANDS


@pytest.mark.parametrize(
    "source",
    [
        "POS_MIN = -(1 << 23)\n",
        "MAX_WAYPOINTS = 255\n",
        "    max_waypoints: int = 255\n",
        "MOTION = (InitMove, MoveTo, Move, GoHome, MoveToWayPoint)\n",
    ],
)
def test_a_fact_written_again_is_seen(source: str) -> None:
    assert any(pattern.search(source) for pattern in FACTS.values())


# --- the one reading of an answer ------------------------------------------------------------


@pytest.mark.parametrize(
    ("cmd", "resp", "text"),
    [
        (IsReady(0), Response.boolean(True), "ready"),
        (IsReady(0), Response.boolean(False), "busy"),
        (GetAbsPos(1), Response.position(-300), "pos=-300"),
        (GetPin(5), Response.boolean(True), "high"),
        (GetPin(5), Response.boolean(False), "low"),
        (SaveWayPoint(0), Response.ok(b"\x00"), "waypoint=0"),
        (SaveWayPoint(0), Response.ok(b"\xfe"), "waypoint=254"),
        (MoveTo(0, True, 5, 0, 0, 0), Response.ok(), "ok"),
        (StopMove(0, False), Response.ok(b"\x01\x02\x03"), "ok, payload 01 02 03"),
        (None, Response.ok(), "ok"),
        (IsReady(0), Response.error(ErrorCode.MOTOR_NOT_READY), "E3 Motor not ready"),
        (None, Response(False, b"\xe9\x00\x00"), "error 0xe9 (unknown code)"),
        (GetAbsPos(0), Response(False, b"\xab\x00\x00"), "error 0xab (unknown code)"),
    ],
    ids=lambda v: str(v),
)
def test_an_answer_reads_one_way(cmd: Command | None, resp: Response, text: str) -> None:
    """codec.describe_answer: the daemon's status, motorctl trace and the replay's text."""
    assert describe_answer(cmd, resp) == text
    assert decode_answer(cmd, resp).text == text


def test_an_answer_carries_its_value_typed() -> None:
    pos = decode_answer(GetAbsPos(1), Response.position(-300))
    assert pos.ack and pos.value == -300 and pos.param is not None
    assert pos.param.field == "position"
    level = decode_answer(GetPin(5), Response.boolean(True))
    assert level.value is True and level.param is not None and level.param.json(True) == 1
    ready = decode_answer(IsReady(0), Response.boolean(False))
    assert ready.param is not None and (ready.param.field, ready.param.json(False)) == (
        "ready",
        False,
    )
    e3 = decode_answer(WaitMoved(0, 5), Response.error(ErrorCode.MOTOR_NOT_READY))
    assert (e3.ack, e3.error, e3.error_byte, e3.value) == (
        False,
        ErrorCode.MOTOR_NOT_READY,
        0xE3,
        None,
    )
    plain = decode_answer(MoveTo(0, True, 5, 0, 0, 0), Response.ok())
    assert plain.param is None and plain.value is None
