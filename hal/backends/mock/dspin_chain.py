"""A daisy chain of mock dSPIN chips (dspin_chip.py) on one chip select, as py-spidev's
``xfer2`` drives it: the part of py-spidev's ``SpiDev`` that motorctl uses (``open``,
``mode``, ``bits_per_word``, ``max_speed_hz``, ``xfer2``, ``close``), so the layer's SPI
code can be handed this in place of the device.

The chain is N 8-bit shift registers in a row: the host's MOSI into chip 0's, chip 0's
out into chip 1's, ..., chip N-1's out to the host's MISO (AN4290's daisy chain). As chip
select falls, each chip loads the byte it has to send; each byte the host clocks shifts
every register one chip along (the last chip's byte goes to the host); as chip select
rises, each chip latches the byte in its register and acts on it. So in a transfer of N
bytes byte i reaches chip N-1-i and the byte received at i came from chip N-1-i; a transfer
of another length leaves the chips bytes that were meant for their neighbours, as real
chips would get them.

The chips want SPI mode 3; a transfer in another mode raises ValueError (the model does not
garble bits as a wrong mode would): ``--probe``'s check of the bus belongs to the layer.
``transfers`` records the last ``keep`` transfers (bytes out, bytes in), the transcript
tests judge, and ``count`` counts them all: a mock daemon runs for months, and its poller
transfers hundreds of times a second (``keep=None`` keeps everything, for tests).

Owned by the thread that drives the mock world; not thread-safe.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

from motorctl.hal.backends.mock.dspin_chip import DspinChip

SPI_MODE_3 = 3


class DspinChain:
    """``chips[0]`` is the chip whose SDI is the host's MOSI."""

    def __init__(self, chips: Sequence[DspinChip], keep: int | None = 100_000) -> None:
        if not chips:
            raise ValueError("a chain has at least one chip")
        self.chips = tuple(chips)
        self.mode = SPI_MODE_3
        self.max_speed_hz = 1_000_000
        self.bits_per_word = 8
        self.opened: tuple[int, int] | None = None
        self.transfers: deque[tuple[bytes, bytes]] = deque(maxlen=keep)
        self.count = 0

    # py-spidev's SpiDev
    def open(self, bus: int, device: int) -> None:
        self.opened = (bus, device)

    def close(self) -> None:
        self.opened = None

    def xfer2(self, values: list[int]) -> list[int]:
        """One transfer with chip select held: ``values`` out, as many bytes back."""
        if self.mode != SPI_MODE_3:
            raise ValueError(f"dSPIN chips need SPI mode 3, the bus is in mode {self.mode}")
        if any(not 0 <= v <= 0xFF for v in values):
            raise ValueError(f"bytes are 0..255: {values}")
        shift = [chip.shift_out() for chip in self.chips]  # chip select falls
        back = []
        for byte in values:
            back.append(shift[-1])
            shift = [byte, *shift[:-1]]
        for chip, byte in zip(self.chips, shift, strict=True):  # chip select rises
            chip.receive(byte)
        self.transfers.append((bytes(values), bytes(back)))
        self.count += 1
        for chip in self.chips:  # the command may have raised or cleared BUSY and FLAG
            chip.changed()
        return back

    # the world's time
    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass for every chip; a moving one may have stopped (BUSY) or
        met a hard stop (FLAG): its listeners hear of it. Time changes nothing on a chip at
        rest (a transfer tells of anything else: ``xfer2``)."""
        for chip in self.chips:
            if chip.motion.idle:
                continue
            chip.advance(dt)
            chip.changed()
