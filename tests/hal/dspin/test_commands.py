"""The command bytes (commands.py) against the datasheet's command structure tables: every
expected byte below is written out from the tables (L6470 9.2, Table 37 and after), not
from the encoder; and the chip's side, decoding them back."""

from __future__ import annotations

import pytest

from motorctl.hal.dspin import commands as c
from motorctl.hal.dspin.chips import L6470, L6472, L6480
from motorctl.hal.dspin.commands import Op

REG = L6470.registers


@pytest.mark.parametrize(
    ("cmd", "expected"),
    [
        (c.simple(Op.NOP), "00"),
        (c.set_param(REG["ACC"], 0x08A), "05 00 8A"),
        (c.set_param(REG["MAX_SPEED"], 0x3FF), "07 03 FF"),
        (c.set_param(REG["KVAL_RUN"], 0x80), "0A 80"),
        (c.set_param(REG["ABS_POS"], -2), "01 3F FF FE"),
        (c.set_param(REG["STEP_MODE"], 0x04), "16 04"),
        (c.get_param(REG["ABS_POS"]), "21"),
        (c.get_param(REG["CONFIG"]), "38"),
        (c.get_param(REG["STATUS"]), "39"),
        (c.run(c.FORWARD, 0x12345), "51 01 23 45"),
        (c.run(c.REVERSE, 0xFFFFF), "50 0F FF FF"),
        (c.step_clock(c.FORWARD), "59"),
        (c.move(c.REVERSE, 0x3FFFFF), "40 3F FF FF"),
        (c.go_to(0x012345), "60 01 23 45"),
        (c.go_to(-1), "60 3F FF FF"),
        (c.go_to_dir(c.FORWARD, -(2**21)), "69 20 00 00"),
        (c.go_until(c.RESET_ABS_POS, c.REVERSE, 0x00400), "82 00 04 00"),
        (c.go_until(c.COPY_TO_MARK, c.FORWARD, 0x00400), "8B 00 04 00"),
        (c.release_sw(c.RESET_ABS_POS, c.FORWARD), "93"),
        (c.release_sw(c.COPY_TO_MARK, c.REVERSE), "9A"),
        (c.simple(Op.GO_HOME), "70"),
        (c.simple(Op.GO_MARK), "78"),
        (c.simple(Op.RESET_POS), "D8"),
        (c.simple(Op.RESET_DEVICE), "C0"),
        (c.simple(Op.SOFT_STOP), "B0"),
        (c.simple(Op.HARD_STOP), "B8"),
        (c.simple(Op.SOFT_HIZ), "A0"),
        (c.simple(Op.HARD_HIZ), "A8"),
        (c.simple(Op.GET_STATUS), "D0"),
    ],
)
def test_each_command_is_its_datasheet_bytes(cmd: c.Command, expected: str) -> None:
    data = cmd.encode()
    assert data == bytes.fromhex(expected)
    # the chip reads it back
    decoded = c.decode(L6470, data[0])
    assert not decoded.wrong and decoded.op is cmd.op
    assert decoded.argument == len(data) - 1
    assert decoded.command(data[1:]) == cmd


def test_what_follows_a_command_byte_in_its_slot() -> None:
    """An argument written after it, or an answer clocked out after it: a transcript's
    reader steps over that many bytes (tests/hal/layers/dspin, hwtest/test_dspin_daemon.py)."""
    assert c.decode(L6470, c.get_param(L6470.registers["ABS_POS"]).encode()[0]).follows == 3
    assert c.decode(L6480, c.get_param(L6480.status_register).encode()[0]).follows == 2
    assert c.decode(L6470, c.simple(Op.GET_STATUS).encode()[0]).follows == 2
    assert c.decode(L6470, c.go_to_dir(1, 5).encode()[0]).follows == 3
    assert c.decode(L6470, c.set_param(L6470.registers["ACC"], 1).encode()[0]).follows == 2
    assert c.decode(L6470, c.simple(Op.SOFT_STOP).encode()[0]).follows == 0


def test_the_l6480_s_config_and_status_addresses() -> None:
    assert c.get_param(L6480.config).encode() == bytes([0x3A])
    assert c.get_param(L6480.status_register).encode() == bytes([0x3B])
    assert c.set_param(L6480.config, 0x2C88).encode() == bytes.fromhex("1A 2C 88")
    # 0x19 is STATUS on the L6470 (read-only: WRONG_CMD) and GATECFG2 on the L6480
    assert c.decode(L6470, 0x19).wrong
    l6480 = c.decode(L6480, 0x19)
    assert l6480.register is L6480.registers["GATECFG2"] and l6480.argument == 1


def test_answers() -> None:
    assert c.get_param(REG["ABS_POS"]).reply_length == 3
    assert c.get_param(REG["STEP_MODE"]).reply_length == 1
    assert c.simple(Op.GET_STATUS).reply_length == 2
    assert c.go_to(5).reply_length == 0 and c.set_param(REG["ACC"], 1).reply_length == 0
    assert c.get_param(REG["SPEED"]).name == "GetParam(SPEED)"
    assert c.run(1, 1).name == "Run"


@pytest.mark.parametrize("byte", [0x20, 0x1B, 0x3C, 0x42, 0x52, 0x61, 0x6A, 0x80, 0x84, 0xFF])
def test_bytes_that_are_no_command(byte: int) -> None:
    assert c.decode(L6470, byte).wrong


def test_read_only_and_reserved_registers() -> None:
    assert c.decode(L6470, 0x04).wrong  # SetParam(SPEED): read-only
    assert not c.decode(L6470, 0x24).wrong  # GetParam(SPEED)
    assert c.decode(L6472, 0x0D).wrong and c.decode(L6472, 0x2D).wrong  # reserved
    with pytest.raises(ValueError, match="read-only"):
        c.set_param(REG["SPEED"], 1).encode()
    with pytest.raises(ValueError, match="needs a register"):
        c.Command(Op.GET_PARAM).encode()


def test_values_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match=r"Run: 1048576 is outside 0..1048575"):
        c.run(c.FORWARD, 1 << 20).encode()
    with pytest.raises(ValueError, match="GoTo: 2097152 is outside"):
        c.go_to(2**21).encode()
    with pytest.raises(ValueError, match="Move: -1 is outside"):
        c.move(c.FORWARD, -1).encode()
    with pytest.raises(ValueError, match="DIR is one bit"):
        c.run(2, 0).encode()
    with pytest.raises(ValueError, match="takes arguments"):
        c.simple(Op.GO_TO)


def test_the_chip_ignores_the_unused_high_bits_of_an_argument() -> None:
    run = c.decode(L6470, 0x51)
    assert run.command(bytes.fromhex("F1 23 45")).value == 0x12345
    go = c.decode(L6470, 0x60)
    assert go.command(bytes.fromhex("FF FF FF")).value == -1
