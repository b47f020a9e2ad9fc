"""A driver's settings as register values (settings.py), and each chip's current scaling
(its Chip, tmc2130.py and tmc5160.py) against the datasheets' formulas."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.layers.tmc.fields import Chip, mres_of
from motorctl.hal.layers.tmc.settings import TmcSettings, register_values
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, Reg


@settings(max_examples=60, deadline=None)
@given(
    chip=st.sampled_from([TMC2130, TMC5160]),
    sense=st.sampled_from([0.05, 0.075, 0.11, 0.22]),
    frac=st.floats(0.05, 1.0),
)
def test_current_scaling_hits_the_requested_current(chip: Chip, sense: float, frac: float) -> None:
    top = (0.32 / (sense + 0.02) if chip is TMC2130 else 0.325 / sense) / math.sqrt(2)
    run = top * frac
    setting = chip.current_setting(sense, run, run / 2)
    step = chip.rms(setting, sense, 31) / 32  # one current-scale step
    assert abs(chip.rms(setting, sense, setting.irun) - run) <= step / 2 + 1e-9
    assert 0 <= setting.ihold <= setting.irun <= 31


def test_impossible_settings_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match=r"above the .* A a TMC2130 gives"):
        TMC2130.current_setting(0.11, 3.0, 1.0)
    with pytest.raises(ValueError, match=r"above the .* A a TMC5160 gives"):
        register_values(TmcSettings(chip=TMC5160, run_current=20.0))
    with pytest.raises(ValueError, match="hold_current <= run_current"):
        TMC5160.current_setting(0.075, 1.0, 1.5)
    with pytest.raises(ValueError, match="power of two"):
        mres_of(12)


@pytest.mark.parametrize("chip", [TMC2130, TMC5160], ids=["tmc2130", "tmc5160"])
def test_each_chip_keeps_its_current_range_where_its_datasheet_says(chip: Chip) -> None:
    """The TMC2130 in CHOPCONF.vsense, the TMC5160 in GLOBALSCALER, written right after
    GCONF; the other registers in the same order for both."""
    regs = register_values(TmcSettings(chip=chip, run_current=0.5, hold_current=0.25))
    chopconf = regs[Reg.CHOPCONF]
    if chip is TMC2130:
        assert list(regs) == [0x00, 0x10, 0x11, 0x14, 0x6D, 0x6C]
        assert chopconf >> 17 & 1 == 1  # 0.5 A fits the high-sensitivity range
    else:
        assert list(regs) == [0x00, 0x0B, 0x10, 0x11, 0x14, 0x6D, 0x6C]
        assert chopconf >> 17 & 1 == 0 and 32 <= (regs[0x0B] or 256) <= 256
