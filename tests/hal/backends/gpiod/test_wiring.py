"""How the config writes a GPIO line (wiring.py): "chip:offset" or a line name, as the
kernel names lines; anything else is refused saying what is accepted."""

from __future__ import annotations

import pytest

from motorctl.hal.backends.gpiod.wiring import LineRef


@pytest.mark.parametrize(
    ("text", "ref"),
    [
        ("gpiochip0:17", LineRef(chip="gpiochip0", offset=17)),
        ("/dev/gpiochip2:0", LineRef(chip="gpiochip2", offset=0)),
        ("pinctrl-bcm2711:4", LineRef(chip="pinctrl-bcm2711", offset=4)),
        ("GPIO17", LineRef(name="GPIO17")),
    ],
)
def test_line_refs_parse_as_the_kernel_names_lines(text: str, ref: LineRef) -> None:
    assert LineRef.parse(text) == ref


@pytest.mark.parametrize(
    "bad", ["", "17", "gpio chip:1", "gpiochip0:x", "gpiochip\x000:1", "GPIO\x0017"]
)
def test_bad_line_refs_are_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="not a GPIO line"):
        LineRef.parse(bad)
