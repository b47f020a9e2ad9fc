"""The daisy chain's framing (chain.py): a GoTo on a chain of three, byte by byte, with the
expected transfers written out from the datasheet's framing (one byte per chip per
transfer, the first byte for the chip at MISO, NOP for the others), not from the encoder;
answers picked out of what comes back."""

from __future__ import annotations

import pytest

from motorctl.hal.dspin import commands as c
from motorctl.hal.dspin.chips import L6470, L6480
from motorctl.hal.dspin.commands import Op
from motorctl.hal.layers.dspin import chain


def test_a_goto_on_a_chain_of_three() -> None:
    # GoTo(ABS_POS = 0x012345) is 0x60 0x01 0x23 0x45 (Table 48). Chip 0 is at MOSI, chip 2
    # at MISO; each transfer is 3 bytes and its first byte ends in chip 2.
    goto = c.go_to(0x012345)
    assert chain.frame(3, {1: goto.encode()}) == (
        bytes([0x00, 0x60, 0x00]),
        bytes([0x00, 0x01, 0x00]),
        bytes([0x00, 0x23, 0x00]),
        bytes([0x00, 0x45, 0x00]),
    )
    assert chain.exchange(3, {0: goto}).transfers == (
        bytes([0x00, 0x00, 0x60]),
        bytes([0x00, 0x00, 0x01]),
        bytes([0x00, 0x00, 0x23]),
        bytes([0x00, 0x00, 0x45]),
    )
    assert chain.exchange(3, {2: goto}).transfers[0] == bytes([0x60, 0x00, 0x00])


def test_commands_for_several_chips_travel_together() -> None:
    transfers = chain.exchange(
        3,
        {
            0: c.simple(Op.SOFT_STOP),
            1: c.run(c.FORWARD, 0x00ABC),
            2: c.set_param(L6470.registers["MAX_SPEED"], 0x041),
        },
    ).transfers
    # chip 2 (byte 0): 07 00 41; chip 1 (byte 1): 51 00 0A BC; chip 0 (byte 2): B0
    assert transfers == (
        bytes([0x07, 0x51, 0xB0]),
        bytes([0x00, 0x00, 0x00]),
        bytes([0x41, 0x0A, 0x00]),
        bytes([0x00, 0xBC, 0x00]),
    )


def test_an_answer_comes_in_the_transfers_after_its_command() -> None:
    ex = chain.exchange(3, {0: c.get_param(L6470.registers["ABS_POS"]), 2: c.simple(Op.GET_STATUS)})
    assert ex.transfers == (
        bytes([0xD0, 0x00, 0x21]),
        bytes(3),
        bytes(3),
        bytes(3),
    )
    received = [
        bytes([0x00, 0x00, 0x00]),
        bytes([0x7E, 0x00, 0x3F]),  # chip 2's STATUS MSB, chip 0's ABS_POS MSB
        bytes([0x03, 0x00, 0xFF]),
        bytes([0x00, 0x00, 0xFE]),
    ]
    assert ex.answers(received) == {0: bytes([0x3F, 0xFF, 0xFE]), 2: bytes([0x7E, 0x03])}
    assert ex.values(received) == {0: -2, 2: 0x7E03}  # ABS_POS sign-extended
    with pytest.raises(ValueError, match="3 transfers back for 4 sent"):
        ex.answers(received[:3])


def test_a_chip_s_bytes_are_picked_from_its_slot() -> None:
    received = [bytes([1, 2, 3]), bytes([4, 5, 6])]
    assert chain.picked(3, 0, received) == bytes([3, 6])
    assert chain.picked(3, 2, received) == bytes([1, 4])
    with pytest.raises(ValueError, match="transfer 1 has 2 bytes for a chain of 3"):
        chain.picked(3, 0, [bytes(3), bytes(2)])


def test_slots() -> None:
    assert [chain.slot(4, k) for k in range(4)] == [3, 2, 1, 0]
    with pytest.raises(ValueError, match="chip 3 is not in a chain of 3"):
        chain.slot(3, 3)
    with pytest.raises(ValueError, match="at least one chip"):
        chain.slot(0, 0)
    assert chain.frame(2, {}) == ()
    assert chain.exchange(1, {0: c.get_param(L6480.config)}).transfers == (
        bytes([0x3A]),
        bytes(1),
        bytes(1),
    )
