"""The board layouts --probe names (hal/backends/gpiod/boards.py), from chip lists as the
kernels of each Raspberry Pi generation show them. Pure functions; the same layouts as real
kernel chips (gpio-sim) run the daemon in `hwtest/run layouts` (hwtest/test_layouts.py)."""

from __future__ import annotations

import pytest

from motorctl.hal.backends.gpiod.boards import board_of, chip_number, describe_chip, layout
from motorctl.hal.backends.gpiod.chip import ChipInfo, chip_list


def chips(*rows: tuple[int, str, int]) -> list[ChipInfo]:
    return [ChipInfo(f"/dev/gpiochip{n}", f"gpiochip{n}", label, lines) for n, label, lines in rows]


BRCMSTB = [
    ("gpio-brcmstb@107d508500", 32),
    ("gpio-brcmstb@107d508520", 4),
    ("gpio-brcmstb@107d517c00", 17),
    ("gpio-brcmstb@107d517c20", 6),
]
PI4 = chips((0, "pinctrl-bcm2711", 58), (1, "raspberrypi-exp-gpio", 8))
PI5_OLD = chips(*[(i, label, n) for i, (label, n) in enumerate(BRCMSTB)], (4, "pinctrl-rp1", 54))
PI5_NEW = chips(
    (0, "pinctrl-rp1", 54), *[(10 + i, label, n) for i, (label, n) in enumerate(BRCMSTB)]
)
PI5_2026 = chips(
    *[(11 + i, label, n) for i, (label, n) in enumerate(BRCMSTB)], (15, "pinctrl-rp1", 54)
)


@pytest.mark.parametrize(
    ("found", "expected"),
    [
        (
            PI4,
            "Raspberry Pi 4 / 400 / CM4 (BCM2711): the header's lines are gpiochip0 "
            "[pinctrl-bcm2711] 58 lines",
        ),
        (
            PI5_OLD,
            "Raspberry Pi 5 / 500 / CM5 (RP1): the header's lines are gpiochip4 [pinctrl-rp1] "
            "54 lines (RP1 as gpiochip4, as kernels before 6.6.45 number it)",
        ),
        (
            PI5_NEW,
            "Raspberry Pi 5 / 500 / CM5 (RP1): the header's lines are gpiochip0 [pinctrl-rp1] "
            "54 lines (RP1 as gpiochip0, as kernels 6.6.45 and later number it)",
        ),
        (
            PI5_2026,
            "Raspberry Pi 5 / 500 / CM5 (RP1): the header's lines are gpiochip15 [pinctrl-rp1] "
            "54 lines (no chip below gpiochip10, as kernels of 2026 (6.12.96+rpt) number them)",
        ),
        (
            chips((0, "pinctrl-bcm2835", 54), (1, "raspberrypi-exp-gpio", 8)),
            "Raspberry Pi 1-3 / Zero (BCM2835-BCM2837): the header's lines are gpiochip0 "
            "[pinctrl-bcm2835] 54 lines",
        ),
    ],
)
def test_each_generation_is_named_with_its_header_chip(
    found: list[ChipInfo], expected: str
) -> None:
    assert layout(found) == expected


def test_a_chip_labelled_like_a_pi_but_sized_otherwise_is_not_one() -> None:
    """The label alone could be any driver's; the line count must match too."""
    text = layout(chips((0, "pinctrl-rp1", 32), (1, "sim-bank1", 16)))
    assert text.startswith("not a Raspberry Pi layout this daemon knows")
    assert "pinctrl-rp1 (54 lines)" in text and "pinctrl-bcm2711 (58 lines)" in text
    assert layout([]).startswith("not a Raspberry Pi layout")


def test_two_header_chips_are_listed_not_guessed() -> None:
    text = layout(chips((0, "pinctrl-rp1", 54), (1, "pinctrl-bcm2711", 58)))
    assert text == (
        "several header chips: gpiochip0 [pinctrl-rp1] 54 lines, "
        "gpiochip1 [pinctrl-bcm2711] 58 lines"
    )


def test_chip_numbers_and_descriptions() -> None:
    assert chip_number("gpiochip0") == 0 and chip_number("gpiochip15") == 15
    assert chip_number("gpiochip") is None and chip_number("gpiochipx") is None
    assert chip_number("spidev0.0") is None
    assert describe_chip(PI4[0]) == "gpiochip0 [pinctrl-bcm2711] 58 lines"
    assert board_of(PI4[1]) is None
    assert chip_list(PI4) == (
        "chips: gpiochip0 [pinctrl-bcm2711] 58 lines, gpiochip1 [raspberrypi-exp-gpio] 8 lines"
    )
    assert chip_list([]) == "the kernel shows no GPIO chips in /dev"
