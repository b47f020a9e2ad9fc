"""CRC-8 algorithms of the reveng catalogue, table-driven: each algorithm's table is built
at its first use (a link uses one of the 20; building them all cost every start of the
daemon and of the client a few ms)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property


def _reflect8(value: int) -> int:
    """Reverse the bit order of one byte."""
    result = 0
    for _ in range(8):
        result = (result << 1) | (value & 1)
        value >>= 1
    return result


def _build_table(poly: int, reflected: bool) -> tuple[int, ...]:
    """256-entry byte table: MSB-first with poly, or LSB-first with the reflected poly."""
    table: list[int] = []
    if reflected:
        rpoly = _reflect8(poly)
        for i in range(256):
            crc = i
            for _ in range(8):
                crc = (crc >> 1) ^ rpoly if crc & 1 else crc >> 1
            table.append(crc)
    else:
        for i in range(256):
            crc = i
            for _ in range(8):
                crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
            table.append(crc)
    return tuple(table)


@dataclass(frozen=True)
class Crc8:
    """One CRC-8 algorithm in Rocksoft/reveng parameter form (width 8)."""

    name: str
    poly: int
    init: int
    refin: bool
    refout: bool
    xorout: int
    check: int

    def __post_init__(self) -> None:
        for attr in ("poly", "init", "xorout", "check"):
            value = getattr(self, attr)
            if not 0 <= value <= 0xFF:
                raise ValueError(f"{self.name}: {attr} {value!r} is not a byte")

    @cached_property
    def _table(self) -> tuple[int, ...]:
        """The byte table, built at the first :meth:`compute` (then an attribute)."""
        return _build_table(self.poly, self.refin)

    def compute(self, data: bytes) -> int:
        """CRC of `data`."""
        table = self._table
        crc = _reflect8(self.init) if self.refin else self.init
        for byte in data:
            crc = table[crc ^ byte]
        # The register holds the CRC in input bit order; flip if the output order differs.
        if self.refin != self.refout:
            crc = _reflect8(crc)
        return crc ^ self.xorout


_ENTRIES = (
    Crc8("CRC-8/AUTOSAR", 0x2F, 0xFF, False, False, 0xFF, 0xDF),
    Crc8("CRC-8/BLUETOOTH", 0xA7, 0x00, True, True, 0x00, 0x26),
    Crc8("CRC-8/CDMA2000", 0x9B, 0xFF, False, False, 0x00, 0xDA),
    Crc8("CRC-8/DARC", 0x39, 0x00, True, True, 0x00, 0x15),
    Crc8("CRC-8/DVB-S2", 0xD5, 0x00, False, False, 0x00, 0xBC),
    Crc8("CRC-8/GSM-A", 0x1D, 0x00, False, False, 0x00, 0x37),
    Crc8("CRC-8/GSM-B", 0x49, 0x00, False, False, 0xFF, 0x94),
    Crc8("CRC-8/HITAG", 0x1D, 0xFF, False, False, 0x00, 0xB4),
    Crc8("CRC-8/I-432-1", 0x07, 0x00, False, False, 0x55, 0xA1),
    Crc8("CRC-8/I-CODE", 0x1D, 0xFD, False, False, 0x00, 0x7E),
    Crc8("CRC-8/LTE", 0x9B, 0x00, False, False, 0x00, 0xEA),
    Crc8("CRC-8/MAXIM-DOW", 0x31, 0x00, True, True, 0x00, 0xA1),
    Crc8("CRC-8/MIFARE-MAD", 0x1D, 0xC7, False, False, 0x00, 0x99),
    Crc8("CRC-8/NRSC-5", 0x31, 0xFF, False, False, 0x00, 0xF7),
    Crc8("CRC-8/OPENSAFETY", 0x2F, 0x00, False, False, 0x00, 0x3E),
    Crc8("CRC-8/ROHC", 0x07, 0xFF, True, True, 0x00, 0xD0),
    Crc8("CRC-8/SAE-J1850", 0x1D, 0xFF, False, False, 0xFF, 0x4B),
    Crc8("CRC-8/SMBUS", 0x07, 0x00, False, False, 0x00, 0xF4),
    Crc8("CRC-8/TECH-3250", 0x1D, 0xFF, True, True, 0x00, 0x97),
    Crc8("CRC-8/WCDMA", 0x9B, 0x00, True, True, 0x00, 0x25),
)

CATALOGUE: dict[str, Crc8] = {entry.name: entry for entry in _ENTRIES}
"""Every CRC-8 of the reveng catalogue, keyed by its canonical upper-case name."""

SMBUS = CATALOGUE["CRC-8/SMBUS"]

ALIASES: dict[str, str] = {
    "CRC-8": "CRC-8/SMBUS",
    "CRC-8/ITU": "CRC-8/I-432-1",
    "CRC-8/MAXIM": "CRC-8/MAXIM-DOW",
    "DOW-CRC": "CRC-8/MAXIM-DOW",
    "CRC-8/AES": "CRC-8/TECH-3250",
    "CRC-8/EBU": "CRC-8/TECH-3250",
}
"""Alias -> canonical name (the aliases the reveng catalogue lists)."""


def _normalise(name: str) -> str:
    key = name.strip().upper().replace("_", "-").replace(" ", "")
    if key == "CRC8":
        return "CRC-8"
    if key.startswith("CRC8/"):
        key = "CRC-8/" + key[len("CRC8/") :]
    return key


def crc8_by_name(name: str) -> Crc8:
    """Look up a CRC-8 by canonical name or alias, case-insensitively.

    "_" is read as "-", and the "CRC-8/" prefix may be left out ("smbus", "maxim-dow").
    Unknown names raise ValueError listing the accepted names.
    """
    key = _normalise(name)
    for candidate in (key, "CRC-8/" + key):
        canonical = ALIASES.get(candidate, candidate)
        if canonical in CATALOGUE:
            return CATALOGUE[canonical]
    accepted = ", ".join([*sorted(CATALOGUE), *sorted(ALIASES)])
    raise ValueError(f"unknown CRC-8 variant {name!r}; accepted names: {accepted}")


# --- checksum names: what a config file (link.checksum) and the CLI (--checksum) accept ------

CHECKSUM_DEFAULT = "crc8"
"""The protocol's checksum: CRC-8/SMBUS."""

CHECKSUM_NONE = "none"
"""No checksum: ignored on input, sent as 0x00."""

CHECKSUM_TEXT = (
    '"crc8" (= CRC-8/SMBUS), "none", or a CRC-8 catalogue name '
    '(e.g. "CRC-8/MAXIM-DOW"; case-insensitive, the "CRC-8/" prefix may be left out)'
)
"""What a checksum name may be, for error messages and help texts."""


def checksum_by_name(name: str) -> Crc8 | None:
    """The CRC a checksum name selects; None for "none" (any case). "crc8" is CRC-8/SMBUS.

    Raises ValueError (listing the accepted names) for an unknown name.
    """
    if name.strip().lower() == CHECKSUM_NONE:
        return None
    return crc8_by_name(name)


def checksum_names() -> str:
    """The catalogue's canonical names, comma-separated (for error messages)."""
    return ", ".join(sorted(CATALOGUE))
