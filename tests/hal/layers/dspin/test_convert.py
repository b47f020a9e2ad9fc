"""The protocol's units to the registers (convert.py): resolution, range, the rounding down,
the clamps and the refused positions, at their edges."""

from __future__ import annotations

import math

import pytest

from motorctl.hal.dspin import scales
from motorctl.hal.layers.dspin import convert
from motorctl.hal.layers.dspin.convert import OutOfRange, Setting


def test_speeds_are_full_steps_and_positions_microsteps() -> None:
    # MoveTo SPEED byte 250 (x 4 = 1000 step/s) on a motor at 1/8 microsteps: 125 full
    # step/s -> MAX_SPEED floor(125 / 15.2588) = 8 (122.07 full step/s = 976.6 step/s)
    s = convert.max_speed(1000, 8)
    assert s == Setting(8, pytest.approx(976.5625), False)  # type: ignore[arg-type]
    # Move SPEED byte 10 (x 4096 = 40960 step/s) at 1/128: 320 full step/s -> SPD 21474
    assert convert.run_speed(40960, 128).register == 21474
    assert convert.run_speed(40960, 128).value <= 40960
    # ACC byte 100 (x 16 = 1600 step/s^2) at full steps: floor(1600 / 14.55) = 109
    assert convert.ramp(1600, 1).register == 109


@pytest.mark.parametrize(
    ("convert_fn", "scale"),
    [
        (convert.run_speed, scales.SPEED),
        (convert.max_speed, scales.MAX_SPEED),
        (convert.ramp, scales.ACC),
        (convert.min_speed, scales.MIN_SPEED),
        (convert.fs_speed, scales.FS_SPD),
    ],
)
def test_each_register_value_is_reached_exactly_and_never_exceeded(
    convert_fn: object, scale: scales.Scale
) -> None:
    assert callable(convert_fn)
    for microsteps in (1, 16, 128):
        for reg in (max(scale.lo, 1), 7, scale.hi):
            exact = float(scale.value(reg) * microsteps)
            assert convert_fn(exact, microsteps).register == reg
            assert float(scale.value(reg) * microsteps) == scale.value(reg) * microsteps
            below = convert_fn(math.nextafter(exact, 0), microsteps)  # a hair below
            if reg > max(scale.lo, 1):
                assert below.register == reg - 1 and not below.clamped
            above = convert_fn(math.nextafter(exact, math.inf), microsteps)
            assert above.register == reg


def test_above_the_range_is_clamped_to_the_largest_value() -> None:
    s = convert.max_speed(20000 * 16, 16)  # 20000 full step/s > 15610
    assert s.register == 0x3FF and s.clamped
    assert s.value == pytest.approx(15609.74 * 16, rel=1e-5)
    assert convert.ramp(1e9, 1) == Setting(0xFFE, float(scales.ACC.value(0xFFE)), True)
    assert convert.run_speed(15625 * 2, 1).register == 2**20 - 1
    assert convert.min_speed(2000, 1).register == 0xFFF


def test_below_the_smallest_step_a_moving_value_becomes_the_smallest() -> None:
    # MoveTo at 4 step/s on a motor at 1/128 microsteps: 0.03 full step/s, below MAX_SPEED's
    # 15.26: the chip will do 15.26 full step/s (1953 step/s), counted as clamped
    s = convert.max_speed(4, 128)
    assert s.register == 1 and s.clamped and s.value == pytest.approx(1953.125)
    assert convert.ramp(1, 1) == Setting(1, float(scales.ACC.lsb), True)
    assert convert.run_speed(0.001, 1).register == 1 and convert.run_speed(0.001, 1).clamped
    # speeds that may be 0 round down to 0, unclamped
    assert convert.min_speed(0.1, 1) == Setting(0, 0.0, False)
    assert convert.run_speed(0, 1) == Setting(0, 0.0, False)
    # FS_SPD 0 is 7.63 full step/s: a threshold below it becomes it
    assert convert.fs_speed(0, 1) == Setting(0, float(scales.FS_SPD.smallest), True)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="microsteps must be >= 1"):
        convert.max_speed(100, 0)
    with pytest.raises(ValueError, match="negative"):
        convert.ramp(-1, 1)


def test_positions_outside_abs_pos_are_refused() -> None:
    assert convert.ABS_POS_MIN == -2_097_152 and convert.ABS_POS_MAX == 2_097_151
    assert convert.position_fits(2_097_151) and convert.position_fits(-2_097_152)
    assert not convert.position_fits(2_097_152) and not convert.position_fits(-2_097_153)
    assert convert.check_position(-5) == -5
    with pytest.raises(OutOfRange, match=r"target 2097152 is outside the dSPIN's ABS_POS range"):
        convert.check_position(2_097_152, "target")
    with pytest.raises(OutOfRange, match="8388607 is outside"):
        convert.check_position(8_388_607)  # the protocol's largest position
    assert convert.check_distance(2**22 - 1) == 2**22 - 1
    with pytest.raises(OutOfRange, match=r"N_STEP 0\.\.4194303"):
        convert.check_distance(2**22)


def test_speed_of_reads_the_speed_register() -> None:
    assert convert.speed_of(2**20 - 1, 1) == pytest.approx(15625, rel=1e-5)
    assert convert.speed_of(67109, 16) == pytest.approx(16000, rel=1e-4)  # 1000 full step/s
