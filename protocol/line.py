"""The serial line under the frames: which baud rates ``--baud`` takes (motorctl, motorctld).

What the layers below accept: pyserial's ``baudrate`` takes any integer >= 0. On Linux it
sets a rate termios names (``B50`` .. ``B4000000``, :data:`STANDARD`) directly and any
other through the kernel's custom-rate interface (``BOTHER``), which the UART's driver
approximates with its divisor or refuses (the open then fails: the tools say so). A PTY
takes any rate and ignores it. 0 is no rate at all: to termios ``B0`` means "hang up"
(drop DTR), and the frame's time at 0 baud is infinite.

The rule here: a whole number of at least 1 baud. Non-standard rates (250000, what some
microcontrollers run at) are accepted, as the kernel accepts them; 0, negatives and
anything that is not a whole number are refused with a message that says what is accepted.

Pure: no I/O.
"""

from __future__ import annotations

__all__ = ["STANDARD", "parse_baud"]

#: the rates termios names on Linux (``B50`` .. ``B4000000``), set without the custom-rate
#: interface
STANDARD = (
    50,
    75,
    110,
    134,
    150,
    200,
    300,
    600,
    1200,
    1800,
    2400,
    4800,
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    460800,
    500000,
    576000,
    921600,
    1000000,
    1152000,
    1500000,
    2000000,
    2500000,
    3000000,
    3500000,
    4000000,
)

_ACCEPTED = (
    "a whole number of baud, e.g. 115200 (the rates termios names, 50 .. 4000000, or any "
    "other the UART's driver can make)"
)


def parse_baud(text: str) -> int:
    """``text`` as a baud rate; ValueError saying why not and what is accepted."""
    word = text.strip()
    try:
        value = int(word, 10)
    except ValueError:
        raise ValueError(f"{word!r} is not a baud rate; accepted: {_ACCEPTED}") from None
    if value == 0:
        raise ValueError(
            f"0 is not a baud rate (to a serial port it means 'hang up'); accepted: {_ACCEPTED}"
        )
    if value < 0:
        raise ValueError(f"{value} is not a baud rate; accepted: {_ACCEPTED}")
    return value
