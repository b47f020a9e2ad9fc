"""Register access over SPI (link.py): 40-bit datagrams, pipelined reads, the echo that
verifies a write, the SPI status byte's flags, a bus where no chip answers."""

from __future__ import annotations

import pytest

from motorctl.hal.layers.tmc.link import TmcError, TmcLink
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import Reg
from tests.support.spi_bench import S2130, SPEED, SpiBench


def test_reads_are_pipelined_and_writes_echo(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    dev = spi_bench.device()
    dev.open()
    assert spi_bench.kernel.opened[0].mode == 3 and spi_bench.kernel.opened[0].max_speed_hz == SPEED
    link = TmcLink(dev, TMC2130)
    assert link.read(Reg.IOIN) >> 24 == 0x11
    tx, _ = model.log[-2]
    assert tx == bytes([0x04, 0, 0, 0, 0])  # a read: bit 7 clear, zero data
    _, rx2 = model.log[-1]
    assert rx2[1:] == (0x11 << 24 | 1 << 6).to_bytes(4, "big")  # answered one datagram later
    link.write(Reg.CHOPCONF, 0x12345678)
    wtx, _ = model.log[-2]
    assert wtx == bytes([0x80 | 0x6C, 0x12, 0x34, 0x56, 0x78])
    assert model.log[-1][1][1:] == bytes([0x12, 0x34, 0x56, 0x78])  # the echo
    assert link.read_many([Reg.GCONF, Reg.CHOPCONF]) == [0, 0x12345678]


def test_status_byte_flags_are_counted_on_their_rising_edge(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()  # the reset flag was up, and went down when GSTAT was read
    counts = drv.link.flag_counts
    assert counts["reset_flag"] == 1 and counts["standstill"] == 1
    model.step_rate, model.stall = 2000.0, True
    for _ in range(3):
        drv.poll()
    assert counts["sg2"] == 1  # one rising edge, however many datagrams saw it
    model.stall = False
    drv.poll()
    model.stall = True
    drv.poll()
    assert counts["sg2"] == 2


def test_a_garbled_write_is_caught_by_its_echo(spi_bench: SpiBench) -> None:
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    real = model.transfer

    def flip_bit(tx: bytes) -> bytes:  # a noisy MOSI line: one data bit flips
        return real(bytes([tx[0], tx[1], tx[2], tx[3], tx[4] ^ 0x10]) if tx[0] & 0x80 else tx)

    model.transfer = flip_bit  # type: ignore[method-assign]
    with pytest.raises(TmcError, match=r"did not receive IHOLD_IRUN .* intact.*spi_speed_hz"):
        drv.link.write(Reg.IHOLD_IRUN, 0x61010)


def test_no_chip_answering_is_a_clear_error(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130", dead=True)
    with pytest.raises(TmcError, match=r"no driver chip answers.*0xffffffff.*VIO"):
        spi_bench.driver(S2130).start()
