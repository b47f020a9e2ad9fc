"""The register scales (scales.py) against the resolutions and ranges the datasheets print
(L6470 9.1.4-9.1.11)."""

from __future__ import annotations

from fractions import Fraction

import pytest

from motorctl.hal.dspin import scales


@pytest.mark.parametrize(
    ("scale", "lsb", "smallest", "largest"),
    [
        (scales.SPEED, 0.015, 0.0, 15625),  # 0 to 15625 step/s, resolution 0.015
        (scales.ACC, 14.55, 14.55, 59590),  # 14.55 to 59590 step/s^2
        (scales.MAX_SPEED, 15.25, 15.25, 15610),  # 15.25 to 15610 step/s
        (scales.MIN_SPEED, 0.238, 0.0, 976.3),  # 0 to 976.3 step/s
        (scales.FS_SPD, 15.25, 7.63, 15617),  # 7.63 to 15625 step/s (see docs/dspin.md)
        (scales.INT_SPEED, 0.0596, 0.0, 976.5),  # 0 to 976.5 step/s
    ],
)
def test_resolution_and_range(
    scale: scales.Scale, lsb: float, smallest: float, largest: float
) -> None:
    assert float(scale.lsb) == pytest.approx(lsb, rel=0.01)
    assert float(scale.smallest) == pytest.approx(smallest, abs=0.01)
    assert float(scale.largest) == pytest.approx(largest, rel=0.001)


def test_the_lsbs_are_powers_of_two_over_the_tick() -> None:
    assert Fraction(250, 10**9) == scales.TICK
    assert scales.SPEED.lsb == Fraction(4_000_000, 2**28)
    assert scales.ACC.lsb == Fraction(4_000_000**2, 2**40)
    assert scales.MAX_SPEED.value(0x41) == Fraction(65 * 4_000_000, 2**18)  # 991.8 step/s
    assert scales.FS_SPD.value(0x27) == Fraction(395, 10) * scales.FS_SPD.lsb  # 602.7 step/s


def test_floor_is_the_largest_register_not_above_a_value() -> None:
    for scale in (scales.SPEED, scales.ACC, scales.MAX_SPEED, scales.FS_SPD):
        for reg in (scale.lo, 1, 100, scale.hi):
            assert scale.floor(scale.value(reg)) == reg
            assert scale.floor(scale.value(reg) - Fraction(1, 10**9)) == reg - 1
