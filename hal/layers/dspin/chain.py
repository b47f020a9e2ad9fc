"""The daisy chain: N dSPIN chips on one chip select, each chip's SDO wired to the next
one's SDI, the host's MOSI to the first chip's SDI and the last chip's SDO to the host's
MISO (AN4290 "daisy chain"; SparkFun's AutoDriver and st_spin drive chains so).

The chips want chip select raised after every byte (SPI mode 3, CS high at least t_disCS =
800 ns between bytes: L6470 Table "SPI timing"), so one transfer (one py-spidev ``xfer2``
call, CS held through it) carries exactly one byte per chip: N bytes. During it, the bytes
shift through the chain: the first byte sent ends in the LAST chip (the one at MISO), the
last byte sent in the first chip (the one at MOSI); the first byte received comes from the
last chip. Byte i of a transfer, sent or received, is chip N-1-i's.

Chips are numbered here from the host's MOSI: chip 0 is the one whose SDI is wired to
MOSI, chip N-1 the one whose SDO is wired to MISO. A command for chip k is sent one byte per
transfer, in consecutive transfers, with NOP (0x00) in the slots of the chips it is not for;
commands for several chips travel together, the shorter ones padded with NOPs. A chip
answers GetParam and GetStatus in the transfers after the command byte (the host sends NOPs
there): so a GetParam of a 3-byte register takes 4 transfers, its answer in the last 3.

Pure: any thread.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from motorctl.hal.dspin.commands import NOP, Command


def slot(length: int, chip: int) -> int:
    """Where chip ``chip`` (0 = at MOSI) is in each transfer over a chain of ``length``."""
    if length < 1:
        raise ValueError(f"a chain has at least one chip, not {length}")
    if not 0 <= chip < length:
        raise ValueError(f"chip {chip} is not in a chain of {length} (0..{length - 1})")
    return length - 1 - chip


def frame(length: int, sequences: Mapping[int, bytes]) -> tuple[bytes, ...]:
    """The transfers that hand each chip its bytes (``sequences``: chip -> bytes, one per
    transfer in order); as many transfers as the longest sequence, NOP elsewhere."""
    count = max((len(s) for s in sequences.values()), default=0)
    transfers = [bytearray([NOP] * length) for _ in range(count)]
    for chip, data in sequences.items():
        i = slot(length, chip)
        for t, byte in enumerate(data):
            transfers[t][i] = byte
    return tuple(bytes(t) for t in transfers)


def picked(length: int, chip: int, received: Sequence[bytes]) -> bytes:
    """The bytes chip ``chip`` sent, one per transfer of ``received``."""
    i = slot(length, chip)
    for t, rx in enumerate(received):
        if len(rx) != length:
            raise ValueError(f"transfer {t} has {len(rx)} bytes for a chain of {length}")
    return bytes(rx[i] for rx in received)


@dataclass(frozen=True)
class Exchange:
    """Commands for some chips of a chain, as the transfers that carry them; ``replies``:
    chip -> (first transfer of its answer, length) for the commands that have one."""

    length: int
    commands: Mapping[int, Command]
    transfers: tuple[bytes, ...]
    replies: Mapping[int, tuple[int, int]]

    def answers(self, received: Sequence[bytes]) -> dict[int, bytes]:
        """Each answering chip's answer out of the transfers ``received`` back."""
        if len(received) != len(self.transfers):
            raise ValueError(f"{len(received)} transfers back for {len(self.transfers)} sent")
        out = {}
        for chip, (start, n) in self.replies.items():
            out[chip] = picked(self.length, chip, received)[start : start + n]
        return out

    def values(self, received: Sequence[bytes]) -> dict[int, int]:
        """The answers as register values (GetParam: sign-extended where signed;
        GetStatus: the STATUS word)."""
        values = {}
        for chip, data in self.answers(received).items():
            reg = self.commands[chip].register
            word = int.from_bytes(data, "big")
            values[chip] = reg.value(word) if reg is not None else word
        return values


def exchange(length: int, commands: Mapping[int, Command]) -> Exchange:
    """The transfers for ``commands`` (chip -> command) sent together: each command's bytes,
    then as many NOPs as its answer has bytes."""
    sequences = {}
    replies = {}
    for chip, cmd in commands.items():
        data = cmd.encode()
        if cmd.reply_length:
            replies[chip] = (len(data), cmd.reply_length)
        sequences[chip] = data + bytes(cmd.reply_length)
    return Exchange(length, dict(commands), frame(length, sequences), replies)
