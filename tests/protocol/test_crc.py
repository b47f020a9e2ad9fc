"""Tests for motorctl.protocol.crc."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from motorctl.protocol.crc import ALIASES, CATALOGUE, SMBUS, Crc8, crc8_by_name

EXPECTED_NAMES = {
    "CRC-8/AUTOSAR",
    "CRC-8/BLUETOOTH",
    "CRC-8/CDMA2000",
    "CRC-8/DARC",
    "CRC-8/DVB-S2",
    "CRC-8/GSM-A",
    "CRC-8/GSM-B",
    "CRC-8/HITAG",
    "CRC-8/I-432-1",
    "CRC-8/I-CODE",
    "CRC-8/LTE",
    "CRC-8/MAXIM-DOW",
    "CRC-8/MIFARE-MAD",
    "CRC-8/NRSC-5",
    "CRC-8/OPENSAFETY",
    "CRC-8/ROHC",
    "CRC-8/SAE-J1850",
    "CRC-8/SMBUS",
    "CRC-8/TECH-3250",
    "CRC-8/WCDMA",
}


def _reflect(value: int) -> int:
    return int(f"{value:08b}"[::-1], 2)


def reference_crc(c: Crc8, data: bytes) -> int:
    """Bit-at-a-time Rocksoft model, independent of the table code."""
    crc = c.init
    for byte in data:
        crc ^= _reflect(byte) if c.refin else byte
        for _ in range(8):
            crc = ((crc << 1) ^ c.poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    if c.refout:
        crc = _reflect(crc)
    return crc ^ c.xorout


def test_catalogue_has_every_reveng_crc8() -> None:
    assert set(CATALOGUE) == EXPECTED_NAMES
    for name, entry in CATALOGUE.items():
        assert entry.name == name


@pytest.mark.parametrize("name", sorted(EXPECTED_NAMES))
def test_check_value(name: str) -> None:
    entry = CATALOGUE[name]
    assert entry.compute(b"123456789") == entry.check
    assert reference_crc(entry, b"123456789") == entry.check


def test_smbus_parameters() -> None:
    assert (SMBUS.poly, SMBUS.init, SMBUS.refin, SMBUS.refout, SMBUS.xorout) == (
        0x07,
        0x00,
        False,
        False,
        0x00,
    )
    assert SMBUS.check == 0xF4
    assert SMBUS.compute(b"") == 0x00


@given(st.sampled_from(sorted(EXPECTED_NAMES)), st.binary(max_size=64))
def test_table_matches_bitwise_reference(name: str, data: bytes) -> None:
    entry = CATALOGUE[name]
    assert entry.compute(data) == reference_crc(entry, data)


def test_custom_parameters_match_reference() -> None:
    # The catalogue has no refin != refout and only bit-symmetric inits (0x00, 0xFF) for
    # reflected CRCs; check those general cases with an asymmetric init (0x1C).
    for refin, refout in ((True, False), (False, True), (True, True), (False, False)):
        c = Crc8("TEST", 0x1D, 0x1C, refin, refout, 0x33, 0x00)
        for data in (b"", b"\x00", b"123456789", bytes(range(256))):
            assert c.compute(data) == reference_crc(c, data)


def test_a_table_is_built_at_its_first_use_only() -> None:
    """Importing the catalogue builds no table (each start would pay for all 20)."""
    c = Crc8("CRC-8/SMBUS", 0x07, 0x00, False, False, 0x00, 0xF4)
    assert "_table" not in vars(c)
    assert c.compute(b"123456789") == 0xF4
    assert vars(c)["_table"] == SMBUS._table  # built once, kept
    assert c == SMBUS and repr(c) == repr(SMBUS)  # not one of its fields


def test_parameters_must_be_bytes() -> None:
    with pytest.raises(ValueError, match="poly"):
        Crc8("BAD", 0x107, 0, False, False, 0, 0)


@pytest.mark.parametrize(
    ("alias", "canonical"),
    [
        ("CRC-8", "CRC-8/SMBUS"),
        ("crc8", "CRC-8/SMBUS"),
        ("CRC-8/ITU", "CRC-8/I-432-1"),
        ("CRC-8/MAXIM", "CRC-8/MAXIM-DOW"),
        ("DOW-CRC", "CRC-8/MAXIM-DOW"),
        ("dow_crc", "CRC-8/MAXIM-DOW"),
        ("CRC-8/AES", "CRC-8/TECH-3250"),
        ("crc-8/ebu", "CRC-8/TECH-3250"),
        ("crc-8/smbus", "CRC-8/SMBUS"),
        ("  Crc-8/Rohc ", "CRC-8/ROHC"),
        ("smbus", "CRC-8/SMBUS"),
        ("maxim-dow", "CRC-8/MAXIM-DOW"),
        ("crc8/sae_j1850", "CRC-8/SAE-J1850"),
    ],
)
def test_lookup_by_alias(alias: str, canonical: str) -> None:
    assert crc8_by_name(alias) is CATALOGUE[canonical]


@pytest.mark.parametrize("name", sorted(EXPECTED_NAMES))
def test_lookup_canonical_any_case(name: str) -> None:
    assert crc8_by_name(name) is CATALOGUE[name]
    assert crc8_by_name(name.lower()) is CATALOGUE[name]


def test_aliases_point_into_catalogue() -> None:
    for canonical in ALIASES.values():
        assert canonical in CATALOGUE


def test_unknown_name_lists_accepted_names() -> None:
    with pytest.raises(ValueError) as info:
        crc8_by_name("CRC-8/NOPE")
    message = str(info.value)
    assert "CRC-8/NOPE" in message
    for name in EXPECTED_NAMES:
        assert name in message
    for alias in ("CRC-8/ITU", "CRC-8/MAXIM", "DOW-CRC", "CRC-8/AES", "CRC-8/EBU"):
        assert alias in message
