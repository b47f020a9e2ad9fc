"""Register access to one TMC chip over SPI: 40-bit datagrams, pipelined reads, echo checks.

The datasheets' SPI protocol (both chips):

- A datagram is 40 bits, MSB first, SPI mode 3: one address byte (bit 7 = write) and 32 data
  bits. The reply's first byte is the SPI status byte; its 32 data bits are *pipelined*: they
  answer the previous datagram (a read's register contents, or the data a write carried).
  So a read is two datagrams, and the datagram after a write echoes the written bits, which
  is how write-only registers are verified here (the chip received exactly these bits).
- The version sits in IOIN bits 31..24: 0x11 for the TMC2130, 0x30 for the TMC5160.

Threads: a link belongs to its driver and is used by whichever thread the driver's caller
is (see ``driver.py``); all SPI traffic of its device node is serialised by the node's
lock (:class:`~motorctl.hal.spi.SpiBus`), and a pipelined read holds it for all its
datagrams.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from motorctl.hal.interfaces import HalError
from motorctl.hal.layers.tmc.fields import SPI_STATUS_BITS, Chip, F, Reg
from motorctl.hal.spi import SpiBus

WRITE: Final = 0x80


class TmcError(HalError):
    """A driver chip that cannot be used as configured; the message names its SPI device."""


class TmcLink:
    """Register access to one chip: 40-bit datagrams, pipelined reads, write echo checks.

    Counts the rising edges of every SPI status flag (``flag_counts``); ``last_status`` is the
    most recent status byte.
    """

    def __init__(self, device: SpiBus, chip: Chip) -> None:
        self.device = device
        self.chip = chip
        self.last_status = 0
        self.flag_counts = dict.fromkeys(SPI_STATUS_BITS[: chip.status_bits], 0)

    def _datagram(self, addr: int, value: int, write: bool) -> tuple[int, int]:
        tx = bytes([addr | (WRITE if write else 0)]) + (value & 0xFFFFFFFF).to_bytes(4, "big")
        rx = self.device.xfer(tx)
        status = rx[0]
        rising = status & ~self.last_status
        for i, name in enumerate(SPI_STATUS_BITS[: self.chip.status_bits]):
            if rising >> i & 1:
                self.flag_counts[name] += 1
        self.last_status = status
        return status, int.from_bytes(rx[1:5], "big")

    def read_many(self, addrs: Sequence[int]) -> list[int]:
        """Read registers in one bus session: n + 1 datagrams, each reply answering the last."""
        if not addrs:
            return []
        out: list[int] = []
        with self.device.session():
            self._datagram(addrs[0], 0, write=False)
            for nxt in [*addrs[1:], addrs[-1]]:  # the last is repeated to fetch its answer
                out.append(self._datagram(nxt, 0, write=False)[1])
        return out

    def read(self, addr: int) -> int:
        return self.read_many([addr])[0]

    def write(self, addr: int, value: int) -> None:
        """Write and check the echo in the next datagram's reply; TmcError when it differs."""
        value &= 0xFFFFFFFF
        with self.device.session():
            self._datagram(addr, value, write=True)
            echo = self._datagram(Reg.IOIN, 0, write=False)[1]
        if echo != value:
            name = self.chip.register_name(addr)
            raise TmcError(
                f"{self.device.path}: {self.chip.name} did not receive {name} "
                f"= 0x{value:08x} intact (it echoed 0x{echo:08x}); check the SPI wiring "
                "(MOSI/MISO/SCK, a common ground) and lower spi_speed_hz"
            )


def identify(link: TmcLink) -> int:
    """The chip's version from IOIN; TmcError naming the device when nothing answers."""
    ioin = link.read(Reg.IOIN)
    version = F.VERSION.get(ioin)
    if ioin in (0, 0xFFFFFFFF):
        raise TmcError(
            f"{link.device.path}: no driver chip answers (IOIN reads 0x{ioin:08x}); check "
            "that the driver has logic power (VIO) and motor power (VM), the wiring of "
            "SCK/SDI/SDO/CSN, and that the bus and chip select are right"
        )
    return version
