"""What the chips share (fields.py) and what each chip is (its Chip in tmc2130.py and
tmc5160.py): every field keyed by a register of its chip, a field's bits, the chips named
by version and by the config's name, one chip object everywhere (pickled as its module's)."""

from __future__ import annotations

import pickle

import pytest

from motorctl.hal.layers.tmc import tmc2130, tmc5160
from motorctl.hal.layers.tmc.config import CHIPS
from motorctl.hal.layers.tmc.fields import Chip, Field
from motorctl.hal.layers.tmc.settings import TmcSettings, TmcSpec


@pytest.mark.parametrize(
    ("module", "chip"), [(tmc2130, tmc2130.TMC2130), (tmc5160, tmc5160.TMC5160)]
)
def test_every_field_is_keyed_by_a_register_of_its_chip(module: object, chip: Chip) -> None:
    fields = {
        name: value
        for name in dir(module.F)  # type: ignore[attr-defined]
        if isinstance(value := getattr(module.F, name), Field)  # type: ignore[attr-defined]
    }
    assert len(fields) > 25
    for name, f in fields.items():
        assert f.reg in chip.registers, f"{chip.name} {name}: register 0x{f.reg:02x}"
        assert f.shift >= 0 and f.shift + f.width <= 32, name
    for f, _ in chip.shorts:
        assert chip.registers[f.reg] == "DRV_STATUS"
    assert {chip.registers[f.reg] for _, f in chip.flags} == {"DRV_STATUS"}
    assert chip.register_name(0x7F) == "register 0x7f"


def test_a_field_puts_and_gets_its_bits_only() -> None:
    sgt = Field(0x6D, 16, 7, signed=True)
    word = sgt.put(0xFFFF, -3)
    assert sgt.get(word) == -3 and word & 0xFFFF == 0xFFFF
    with pytest.raises(ValueError, match="does not fit a 7-bit field"):
        sgt.put(0, 64)


def test_the_chips_by_name_and_version() -> None:
    assert {name: chip.version for name, chip in CHIPS.items()} == {
        "tmc2130": 0x11,
        "tmc5160": 0x30,
    }
    assert [c.name.lower() for c in CHIPS.values()] == list(CHIPS)


def test_a_chip_is_one_object_across_a_pickle() -> None:
    """A driver spec crosses into the step executor's process: its chip stays the chip."""
    spec = TmcSpec("/dev/spidev0.0", TmcSettings(chip=tmc5160.TMC5160), ramp=True)
    again = pickle.loads(pickle.dumps(spec))
    assert again.settings.chip is tmc5160.TMC5160 and again == spec
