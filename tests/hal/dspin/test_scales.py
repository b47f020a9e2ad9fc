"""The register scales (scales.py) against the resolutions and ranges the datasheets print
(L6470 9.1.4-9.1.11)."""

from __future__ import annotations

from fractions import Fraction

import pytest

from motorctl.hal.dspin import scales
from tests.support import REPO


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


DOC_SCALES = {
    "SPEED, Run and GoUntil's SPD": scales.SPEED,
    "ACC, DEC": scales.ACC,
    "MAX_SPEED": scales.MAX_SPEED,
    "MIN_SPEED": scales.MIN_SPEED,
    "FS_SPD": scales.FS_SPD,
    "INT_SPEED": scales.INT_SPEED,
}


def test_docs_unit_table_is_the_code_s() -> None:
    units = [r for r in doc_table_after("Units", "register") if r[0] in DOC_SCALES]
    assert [r[0] for r in units] == list(DOC_SCALES)
    for name, _format, resolution, reg_range, full_range in units:
        scale = DOC_SCALES[name]
        assert float(scale.lsb) == pytest.approx(float(resolution.split()[0]), rel=0.005)
        lo, hi = (int(x, 16) for x in reg_range.split(".."))
        assert (lo, hi) == (scale.lo, scale.hi), name
        small, large = (float(x) for x in full_range.split(".."))
        assert float(scale.smallest) == pytest.approx(small, abs=0.01), name
        assert float(scale.largest) == pytest.approx(large, rel=1e-4), name


def doc_table_after(section: str, first_header: str) -> list[list[str]]:
    """The rows of the first table with ``first_header`` after ``## section``."""
    lines = (REPO / "docs" / "dspin.md").read_text(encoding="utf-8").splitlines()
    after = lines.index(f"## {section}")
    start = next(
        i for i, line in enumerate(lines) if i > after and line.startswith(f"| {first_header} |")
    )
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows
