"""Frame builders: commands as the host sends them, answers as the host reads them, and
hand-made frames checked by a reference CRC that does not come from motorctl.protocol.crc.
"""

from __future__ import annotations

from motorctl.protocol.codec import CodecOptions, Command, Response, decode_response, encode_command

#: The protocol's default options (CRC-8/SMBUS, strict padding).
OPTS = CodecOptions()


def frame(*cmds: Command, opts: CodecOptions = OPTS) -> bytes:
    """The command frames of ``cmds``, back to back."""
    return b"".join(encode_command(c, opts) for c in cmds)


def answers(data: bytes | bytearray, opts: CodecOptions = OPTS) -> list[Response]:
    """The 5-byte answers in ``data`` (whole answers only)."""
    assert len(data) % 5 == 0, f"{len(data)} bytes are not whole answers"
    return [decode_response(bytes(data[i : i + 5]), opts) for i in range(0, len(data), 5)]


def ref_crc8(data: bytes, poly: int = 0x07) -> int:
    """Bitwise CRC-8/SMBUS (init 0, not reflected, xorout 0); independent of protocol.crc."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def raw_frame(body: bytes | str) -> bytes:
    """A command frame made by hand: ``body`` (bytes, or hex), zero padding to 9 bytes, the
    reference CRC."""
    raw = bytes.fromhex(body) if isinstance(body, str) else body
    raw += bytes(9 - len(raw))
    return raw + bytes([ref_crc8(raw)])
