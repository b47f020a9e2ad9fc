"""A chain of three mock dSPIN chips (dspin_chain.py) as py-spidev's xfer2 drives it: the
transfers of a GoTo written out byte by byte from the datasheet's framing reach the middle
chip only; answers come back in the slots the framing gives; the layer's framing
(hal/layers/dspin/chain.py) drives the same chain."""

from __future__ import annotations

import pytest

from motorctl.hal.backends.mock.dspin_chain import DspinChain
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.dspin import commands as c
from motorctl.hal.dspin.chips import L6470, L6480, POWERSTEP01_VOLTAGE
from motorctl.hal.dspin.commands import Op
from motorctl.hal.layers.dspin import chain as framing


def three() -> DspinChain:
    """An L6470 at MOSI (chip 0), an L6480, a powerSTEP01 at MISO (chip 2)."""
    return DspinChain([DspinChip(L6470), DspinChip(L6480), DspinChip(POWERSTEP01_VOLTAGE)])


def xfer(bus: DspinChain, *transfers: str) -> list[bytes]:
    return [bytes(bus.xfer2(list(bytes.fromhex(t)))) for t in transfers]


def test_a_goto_transcript_on_a_chain_of_three() -> None:
    bus = three()
    # GetStatus to every chip: D0 D0 D0, then two NOP transfers carry the answers back;
    # the first byte received is the powerSTEP01's (at MISO), the last the L6470's
    back = xfer(bus, "D0 D0 D0", "00 00 00", "00 00 00")
    assert back[0] == bytes(3)
    assert back[1] == bytes([0xE4, 0xE4, 0x7C])  # STATUS MSBs: UVLO latched at power-up
    assert back[2] == bytes([0x13, 0x13, 0x13])  # HiZ, not BUSY, DIR forward
    # GoTo(ABS_POS = 0x000400) to the L6480 in the middle: 60 00 04 00, NOP for the others
    assert xfer(bus, "00 60 00", "00 00 00", "00 04 00", "00 00 00") == [bytes(3)] * 4
    assert [chip.busy for chip in bus.chips] == [False, True, False]
    bus.advance(3)
    # GetParam(ABS_POS) = 0x21 to all three, three NOP transfers for the 22 bits
    back = xfer(bus, "21 21 21", "00 00 00", "00 00 00", "00 00 00")
    assert back[1:] == [bytes([0, 0x00, 0]), bytes([0, 0x04, 0]), bytes([0, 0x00, 0])]
    assert bus.transfers[3] == (bytes.fromhex("00 60 00"), bytes(3))


def test_the_layer_s_framing_drives_the_chain() -> None:
    bus = three()
    goto = framing.exchange(3, {2: c.go_to(-1000)})
    for t in goto.transfers:
        bus.xfer2(list(t))
    bus.advance(5)
    get = framing.exchange(
        3, {k: c.get_param(chip.chip.registers["ABS_POS"]) for k, chip in enumerate(bus.chips)}
    )
    back = [bytes(bus.xfer2(list(t))) for t in get.transfers]
    assert get.values(back) == {0: 0, 1: 0, 2: -1000}
    config = framing.exchange(
        3, {k: c.get_param(chip.chip.config) for k, chip in enumerate(bus.chips)}
    )
    back = [bytes(bus.xfer2(list(t))) for t in config.transfers]
    assert config.values(back) == {0: 0x2E88, 1: 0x2C88, 2: 0x2C88}
    status = framing.exchange(3, {1: c.simple(Op.GET_STATUS)})
    back = [bytes(bus.xfer2(list(t))) for t in status.transfers]
    assert L6480.status.decode(status.values(back)[1]).faults == ("UVLO",)


def test_a_transfer_of_another_length_feeds_the_neighbours() -> None:
    bus = three()
    bus.xfer2([0xD0])  # one byte: the L6470 gets GetStatus, the others what it shifted
    back = bus.xfer2([0, 0, 0, 0])  # four bytes: the first comes from the powerSTEP01
    assert back[2] == 0x7C  # the L6470's STATUS MSB, two chips along


def test_mode_and_bytes() -> None:
    bus = three()
    bus.open(0, 1)
    assert bus.opened == (0, 1)
    bus.mode = 0
    with pytest.raises(ValueError, match="need SPI mode 3, the bus is in mode 0"):
        bus.xfer2([0, 0, 0])
    bus.mode = 3
    with pytest.raises(ValueError, match=r"bytes are 0\.\.255"):
        bus.xfer2([256, 0, 0])
    bus.close()
    assert bus.opened is None
    with pytest.raises(ValueError, match="at least one chip"):
        DspinChain([])


def test_the_transcript_keeps_the_last_transfers_and_counts_them_all() -> None:
    """A mock daemon's poller transfers hundreds of times a second for months: the record
    is bounded, the count is not."""
    bus = DspinChain([DspinChip(L6470)], keep=3)
    xfer(bus, "00", "00", "D0", "00", "00")
    assert bus.count == 5
    assert list(bus.transfers) == [
        (bytes.fromhex("D0"), bytes(1)),
        (bytes.fromhex("00"), bytes([0x7C])),  # STATUS MSB, as in the chain of three
        (bytes.fromhex("00"), bytes([0x13])),
    ]
