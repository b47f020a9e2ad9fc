"""The baud rates ``--baud`` takes (protocol/line.py), the rule of motorctl and motorctld:
termios's own rates and any other whole number of baud; 0 (termios's "hang up"), negatives
and what is not a whole number are refused, saying what is accepted."""

from __future__ import annotations

import termios

import pytest

from motorctl.protocol.line import STANDARD, parse_baud


def test_the_standard_rates_are_the_ones_termios_names() -> None:
    named = {int(n[1:]) for n in dir(termios) if n.startswith("B") and n[1:].isdigit()}
    assert set(STANDARD) == named - {0}


@pytest.mark.parametrize("text", ["115200", " 9600", "250000", "4000000", "12000000", "1"])
def test_whole_rates_are_taken_standard_or_not(text: str) -> None:
    assert parse_baud(text) == int(text)


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("0", "0 is not a baud rate (to a serial port it means 'hang up')"),
        ("-5", "-5 is not a baud rate"),
        (" -5", "-5 is not a baud rate"),  # as motorctl's parser hands negatives over
        ("1e5", "'1e5' is not a baud rate"),
        ("115200.0", "'115200.0' is not a baud rate"),
        ("0x100", "'0x100' is not a baud rate"),
    ],
)
def test_what_is_no_rate_is_refused_saying_what_is(text: str, why: str) -> None:
    with pytest.raises(ValueError) as exc:
        parse_baud(text)
    assert str(exc.value).startswith(why + "; accepted: a whole number of baud, e.g. 115200")
