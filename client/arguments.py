"""argparse types of the tools' numbers (``motorctl tap``, ``trace``, ``replay``): a number
in a range, refused in one line when it is none, not finite (``nan``, ``inf``: a wait that
never ends, a tolerance nothing compares with) or outside the range.

Threads: none of its own; the caller's, while argparse parses.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["number_in", "whole_in"]


def number_in(lo: float, hi: float, unit: str, *, lo_open: bool = False) -> Callable[[str], float]:
    """argparse type: a finite number in ``lo..hi`` (``lo`` itself refused with
    ``lo_open``); ``unit`` names what it counts in the message (``"ms"``, ``"s"``, ``"%"``)."""
    above = f"more than {lo:g}" if lo_open else f"at least {lo:g}"
    span = f"{above} and at most {hi:g} {unit}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        low_ok = value > lo if lo_open else value >= lo
        if not (low_ok and value <= hi):  # nan and inf fail here too
            shown = text.strip()  # motorctl's parser puts a space before a negative number
            raise argparse.ArgumentTypeError(f"{shown!r} is not a number {span}")
        return value

    parse.__name__ = "number"
    return parse


def whole_in(lo: int, hi: int, unit: str) -> Callable[[str], int]:
    """argparse type: a whole number in ``lo..hi`` (``unit`` names what it counts)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            shown = text.strip()
            raise argparse.ArgumentTypeError(f"{shown!r} is not a whole number of {unit}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is not in {lo}..{hi} {unit}")
        return value

    parse.__name__ = "whole number"
    return parse
