"""The register maps (registers.py) against the datasheets' register tables: addresses,
lengths, reset values and write conditions per model, and where the models differ."""

from __future__ import annotations

import pytest

from motorctl.hal.dspin.chips import (
    CHIPS,
    L6470,
    L6472,
    L6480,
    POWERSTEP01_CURRENT,
    POWERSTEP01_VOLTAGE,
    Chip,
)
from motorctl.hal.dspin.registers import Access, Field, Register, RegisterMap
from tests.support import REPO

#: (name, address, bits, reset) of the L6470, from ST's table (X-CUBE-SPN2 L6470.c,
#: transcribing the datasheet's Table 9 "Register map")
L6470_TABLE = [
    ("ABS_POS", 0x01, 22, 0x000000),
    ("EL_POS", 0x02, 9, 0x000),
    ("MARK", 0x03, 22, 0x000000),
    ("SPEED", 0x04, 20, 0x0000),
    ("ACC", 0x05, 12, 0x08A),
    ("DEC", 0x06, 12, 0x08A),
    ("MAX_SPEED", 0x07, 10, 0x041),
    ("MIN_SPEED", 0x08, 13, 0x000),
    ("FS_SPD", 0x15, 10, 0x027),
    ("KVAL_HOLD", 0x09, 8, 0x29),
    ("KVAL_RUN", 0x0A, 8, 0x29),
    ("KVAL_ACC", 0x0B, 8, 0x29),
    ("KVAL_DEC", 0x0C, 8, 0x29),
    ("INT_SPEED", 0x0D, 14, 0x0408),
    ("ST_SLP", 0x0E, 8, 0x19),
    ("FN_SLP_ACC", 0x0F, 8, 0x29),
    ("FN_SLP_DEC", 0x10, 8, 0x29),
    ("K_THERM", 0x11, 4, 0x0),
    ("OCD_TH", 0x13, 4, 0x8),
    ("STALL_TH", 0x14, 7, 0x40),
    ("STEP_MODE", 0x16, 8, 0x7),
    ("ALARM_EN", 0x17, 8, 0xFF),
    ("CONFIG", 0x18, 16, 0x2E88),
]


@pytest.mark.parametrize(("name", "addr", "bits", "reset"), L6470_TABLE)
def test_the_l6470_map_is_st_s_table(name: str, addr: int, bits: int, reset: int) -> None:
    reg = L6470.registers[name]
    assert (reg.addr, reg.bits, reg.reset) == (addr, bits, reset)
    assert L6470.registers.at(addr) is reg


def test_config_and_status_move_on_the_l6480_and_powerstep01() -> None:
    for chip in (L6470, L6472):
        assert (chip.config.addr, chip.status_register.addr) == (0x18, 0x19)
        assert chip.config.reset == 0x2E88
    for chip in (L6480, POWERSTEP01_VOLTAGE, POWERSTEP01_CURRENT):
        assert (chip.config.addr, chip.status_register.addr) == (0x1A, 0x1B)
        assert chip.config.reset == 0x2C88
        assert chip.registers.at(0x18) is chip.registers["GATECFG1"]
        assert chip.registers.at(0x19) is chip.registers["GATECFG2"]
        assert chip.registers["FS_SPD"].bits == 11  # BOOST_MODE at bit 10
        assert chip.registers["OCD_TH"].bits == 5
    assert L6470.registers.at(0x1A) is None and L6470.registers.at(0x1B) is None


def test_the_current_mode_chips_have_tval_where_the_voltage_mode_has_kval() -> None:
    for chip in (L6472, POWERSTEP01_CURRENT):
        for addr, name in ((0x09, "TVAL_HOLD"), (0x0E, "T_FAST"), (0x0F, "TON_MIN")):
            reg = chip.registers.at(addr)
            assert reg is not None and reg.name == name
        assert chip.registers["TVAL_RUN"].bits == 7
        assert "KVAL_RUN" not in chip.registers
    for chip in (L6470, L6480, POWERSTEP01_VOLTAGE):
        assert chip.registers.at(0x0A) is chip.registers["KVAL_RUN"]
        assert "TVAL_RUN" not in chip.registers
    # the L6472 has no BEMF compensation and no stall detection: reserved addresses
    for addr in (0x0D, 0x11, 0x14):
        assert L6472.registers.at(addr) is None
    assert L6470.registers["STALL_TH"].bits == 7 and L6480.registers["STALL_TH"].bits == 5


@pytest.mark.parametrize("chip", list(CHIPS.values()), ids=list(CHIPS))
def test_write_conditions(chip: Chip) -> None:
    regs = chip.registers
    assert regs["STEP_MODE"].access is Access.HIZ  # writable in HiZ only
    assert regs["CONFIG"].access is Access.HIZ
    for name in ("ABS_POS", "EL_POS", "ACC", "DEC", "MIN_SPEED", "ALARM_EN"):
        assert regs[name].access is Access.STOPPED, name
    for name in ("MARK", "MAX_SPEED", "FS_SPD", "OCD_TH"):
        assert regs[name].access is Access.ALWAYS, name
    for name in ("SPEED", "ADC_OUT", "STATUS"):
        assert not regs[name].access.writable
    assert regs["STATUS"].reset is None and regs["STATUS"].bits == 16


def test_a_signed_register_holds_22_bits_of_twos_complement() -> None:
    abs_pos = L6470.registers["ABS_POS"]
    assert abs_pos.nbytes == 3 and abs_pos.signed
    assert abs_pos.word(-1) == 0x3FFFFF
    assert abs_pos.word(-(2**21)) == 0x200000
    assert abs_pos.value(0x3FFFFF) == -1 and abs_pos.value(0x1FFFFF) == 2**21 - 1
    assert abs_pos.value(0xFFFFFF) == -1  # the bits above 22 are ignored
    with pytest.raises(ValueError, match=r"outside -2097152\.\.2097151"):
        abs_pos.word(2**21)
    acc = L6470.registers["ACC"]
    assert acc.word(0xFFF) == 0xFFF and acc.nbytes == 2
    with pytest.raises(ValueError, match=r"outside 0\.\.4095"):
        acc.word(0x1000)


def test_fields() -> None:
    config = L6470.config
    assert config.field("SW_MODE").get(0x2E88) == 0  # hard stop on the switch at reset
    assert config.field("OC_SD").get(0x2E88) == 1
    assert config.field("SW_MODE").put(0x2E88, 1) == 0x2E98
    with pytest.raises(ValueError, match="does not fit"):
        Field("X", 0, 2).put(0, 4)
    with pytest.raises(KeyError, match="no field NOPE"):
        config.field("NOPE")
    step_mode = POWERSTEP01_CURRENT.registers["STEP_MODE"]
    assert step_mode.field("CM_VM").mask == 0x08


def test_a_map_names_each_register_and_address_once() -> None:
    a = Register("A", 0x01, 8, 0, Access.ALWAYS)
    with pytest.raises(ValueError, match="once"):
        RegisterMap((a, Register("B", 0x01, 8, 0, Access.ALWAYS)))
    with pytest.raises(KeyError, match="no register B"):
        RegisterMap((a,))["B"]
    assert [r.name for r in RegisterMap((a,))] == ["A"]


def doc_table(first_header: str) -> list[list[str]]:
    """The rows of the table of docs/dspin.md whose first header cell is ``first_header``."""
    lines = (REPO / "docs" / "dspin.md").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header} |"))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


ACCESS_WORDS = {
    "always": Access.ALWAYS,
    "stopped": Access.STOPPED,
    "HiZ": Access.HIZ,
    "read-only": Access.READ_ONLY,
}
DOC_CHIPS = {
    "L6470": L6470,
    "L6472": L6472,
    "L6480": L6480,
    "powerSTEP01": POWERSTEP01_VOLTAGE,
    "powerSTEP01-current": POWERSTEP01_CURRENT,
}


def test_docs_register_table_is_the_code_s() -> None:
    seen: dict[str, set[str]] = {key: set() for key in DOC_CHIPS}
    rows = doc_table("register")
    assert len(rows) > 35
    for name, addr, bits, reset, writable, chips in rows:
        keys = list(DOC_CHIPS) if chips == "all" else chips.split(", ")
        for key in keys:
            reg = DOC_CHIPS[key].registers[name]
            assert reg.addr == int(addr, 16) and reg.bits == int(bits), (key, name)
            assert reg.reset == (None if reset == "-" else int(reset, 16)), (key, name)
            assert reg.access is ACCESS_WORDS[writable], (key, name)
            seen[key].add(name)
    for key, chip in DOC_CHIPS.items():
        assert seen[key] == {r.name for r in chip.registers}, key
