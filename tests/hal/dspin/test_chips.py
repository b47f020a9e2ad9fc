"""The chips (chips.py): step modes and their limits, the powerSTEP01's two modes, the
ALARM_EN bits, names."""

from __future__ import annotations

import pytest

from motorctl.hal.dspin.chips import (
    CHIPS,
    L6470,
    L6472,
    L6480,
    POWERSTEP01_CURRENT,
    POWERSTEP01_VOLTAGE,
)


def test_step_sel_selects_a_power_of_two_up_to_each_chip_s_limit() -> None:
    assert [L6470.microsteps(s) for s in range(8)] == [1, 2, 4, 8, 16, 32, 64, 128]
    assert [L6472.microsteps(s) for s in range(8)] == [1, 2, 4, 8, 16, 16, 16, 16]
    assert POWERSTEP01_CURRENT.microsteps(7) == 16 and POWERSTEP01_VOLTAGE.microsteps(7) == 128
    assert L6480.step_sel(128) == 7 and L6472.step_sel(16) == 4
    with pytest.raises(ValueError, match="cannot do 32 microsteps per step: it does 1, 2"):
        L6472.step_sel(32)
    with pytest.raises(ValueError, match="cannot do 3 microsteps"):
        L6470.step_sel(3)
    with pytest.raises(ValueError, match="STEP_SEL is 3 bits"):
        L6470.microsteps(8)


def test_the_powerstep01_s_mode_is_step_mode_cm_vm() -> None:
    assert POWERSTEP01_CURRENT.step_mode(16) == 0x0C  # CM_VM | STEP_SEL 1/16
    assert POWERSTEP01_VOLTAGE.step_mode(16) == 0x04
    assert L6470.step_mode(128) == 0x07


def test_names_and_features() -> None:
    assert set(CHIPS) == {"l6470", "l6472", "l6480", "powerstep01", "powerstep01-current"}
    assert POWERSTEP01_CURRENT.name == "powerSTEP01 (current mode)"
    assert L6480.name == "L6480"
    assert not L6472.has_stall_detection
    assert all(c.has_stall_detection for c in (L6470, L6480, POWERSTEP01_CURRENT))
    assert L6470.alarms[4] == "STEP_LOSS_A" and L6472.alarms[4] is None
    assert L6480.alarms[4] == "UVLO_ADC" and L6480.alarms[7] == "CMD_ERROR"


def test_the_config_names_every_chip_and_the_counter_is_abs_pos() -> None:
    # the declaration names the chips without importing their tables (a light config)
    from motorctl.hal.dspin.chips import Chip
    from motorctl.hal.dspin.counter import ABS_POS_BITS, ABS_POS_SPAN
    from motorctl.hal.dspin.spec import DspinSpec
    from motorctl.hal.layers.dspin.config import CHIPS as DECLARED

    assert DECLARED == CHIPS and tuple(DECLARED) == tuple(CHIPS)
    assert all(isinstance(DspinSpec("/dev/spidev0.0", 0, k, 16).model, Chip) for k in DECLARED)
    assert {c.registers["ABS_POS"].bits for c in CHIPS.values()} == {ABS_POS_BITS}
    assert ABS_POS_SPAN == 1 << 22
