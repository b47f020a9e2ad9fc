"""Which board a machine's GPIO chips say it is, for ``motorctld --probe`` and for the errors
that list the chips: the Raspberry Pi layouts, told apart by the label and line count of the
chip that carries the 40-pin header, and how the kernel numbered that chip.

Pure: a list of chips in, text out; no I/O, no hardware library. Immutable tables: any
thread may read them.

The header chip's number is the kernel's to choose and has changed more than once (a config
should name lines, ``GPIO17``, or the chip by its label, ``pinctrl-rp1:17``, not by number):

- Raspberry Pi 4/400/CM4: ``pinctrl-bcm2711`` (58 lines) is gpiochip0, the firmware's
  ``raspberrypi-exp-gpio`` (8 lines) gpiochip1.
- Raspberry Pi 5/500/CM5 before kernel 6.6.45: the SoC's four ``gpio-brcmstb@...`` chips are
  gpiochip0..3 and the RP1's ``pinctrl-rp1`` (54 lines, the header) gpiochip4.
- 6.6.45 and later (raspberrypi/linux#6144): ``pinctrl-rp1`` is gpiochip0, the SoC's chips
  gpiochip10..13; Raspberry Pi OS links /dev/gpiochip4 to gpiochip0 for old programs.
- Kernels of 2026 (6.12.96+rpt, Adafruit_Blinka#1119): no chip below gpiochip10 at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Protocol


class Chip(Protocol):
    """What a layout needs to know of a chip (``chip.ChipInfo`` has it)."""

    @property
    def name(self) -> str: ...

    @property
    def label(self) -> str: ...

    @property
    def num_lines(self) -> int: ...


@dataclass(frozen=True)
class Board:
    """A board family by the chip that carries its 40-pin header."""

    name: str
    label: str
    num_lines: int


BOARDS: Final = (
    Board("Raspberry Pi 4 / 400 / CM4 (BCM2711)", "pinctrl-bcm2711", 58),
    Board("Raspberry Pi 5 / 500 / CM5 (RP1)", "pinctrl-rp1", 54),
    Board("Raspberry Pi 1-3 / Zero (BCM2835-BCM2837)", "pinctrl-bcm2835", 54),
)


def chip_number(name: str) -> int | None:
    """17 for ``gpiochip17``; None for a name that is not ``gpiochipN``."""
    tail = name[len("gpiochip") :] if name.startswith("gpiochip") else ""
    return int(tail) if tail.isdigit() else None


def describe_chip(chip: Chip) -> str:
    """``gpiochip4 [pinctrl-rp1] 54 lines``: number, label and line count, as errors list them."""
    return f"{chip.name} [{chip.label}] {chip.num_lines} lines"


def _numbering(header: Chip, chips: Sequence[Chip]) -> str:
    """How the kernel numbered a Raspberry Pi 5's chips, as far as the numbers tell."""
    numbers = [n for n in (chip_number(c.name) for c in chips) if n is not None]
    own = chip_number(header.name)
    if numbers and min(numbers) >= 10:
        return "no chip below gpiochip10, as kernels of 2026 (6.12.96+rpt) number them"
    if own == 4:
        return "RP1 as gpiochip4, as kernels before 6.6.45 number it"
    if own == 0:
        return "RP1 as gpiochip0, as kernels 6.6.45 and later number it"
    return f"RP1 as {header.name}"


def board_of(chip: Chip) -> Board | None:
    """The board family whose header this chip carries, if any."""
    return next(
        (b for b in BOARDS if chip.label == b.label and chip.num_lines == b.num_lines), None
    )


def layout(chips: Sequence[Chip]) -> str:
    """The board these chips belong to and where its header's lines are, in one line, e.g.
    ``Raspberry Pi 5 / 500 / CM5 (RP1): the header's lines are gpiochip0 [pinctrl-rp1]
    54 lines (RP1 as gpiochip0, as kernels 6.6.45 and later number it)``."""
    headers = [(c, b) for c in chips if (b := board_of(c)) is not None]
    if len(headers) == 1:
        ((header, board),) = headers
        text = f"{board.name}: the header's lines are {describe_chip(header)}"
        if board.label == "pinctrl-rp1":
            text += f" ({_numbering(header, chips)})"
        return text
    if headers:
        return "several header chips: " + ", ".join(describe_chip(c) for c, _ in headers)
    known = ", ".join(f"{b.label} ({b.num_lines} lines)" for b in BOARDS)
    return f"not a Raspberry Pi layout this daemon knows (no chip {known})"
