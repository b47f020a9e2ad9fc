"""The capability "lines a compiled core may drive": a :class:`~motorctl.hal.interfaces.StepIO`'s
STEP/DIR and end-stop lines as a compiled step core (motion/executors/csrc) drives them, with
no Python per step: raw kernel GPIO requests (:class:`ChardevLines`) or a simulated machine's
cells and timeline (:class:`SimulatedLines`).

An optional part of the backend contract (hal/contract.py, ``Backend.compiled_lines``: a
backend that has none says why, the default); the registry puts what a backend gives into
``StepIO.compiled`` (or the reason into ``StepIO.compiled_missing``). The lines stay the
backend's: it releases them when the StepIO closes. Immutable values; a compiled core that
takes them owns them (in its thread) until it stops.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

#: why a StepIO has no compiled lines when its backend gives none
NO_COMPILED_LINES: Final = "the backend hands no lines to a compiled core"


@dataclass(frozen=True)
class ChardevRequest:
    """One kernel GPIO line request, as its file descriptor (the backend keeps owning it).

    ``uapi``: 2 for a ``GPIO_V2_GET_LINE_IOCTL`` request (lines set with a mask,
    ``GPIO_V2_LINE_SET_VALUES_IOCTL``; events ``struct gpio_v2_line_event``), 1 for a v1
    line handle (``GPIOHANDLE_SET_LINE_VALUES_IOCTL`` sets every line of it at once) or a
    v1 event request (one line, ``struct gpioevent_data``). ``offsets``: the chip's line
    offsets in the request's order (the kernel's bit i / ``values[i]``). ``levels``: an
    output request's driven physical levels, in that order (a v1 write repeats them).
    """

    fd: int
    uapi: int
    offsets: tuple[int, ...]
    levels: tuple[bool, ...] = ()


@dataclass(frozen=True)
class ChardevLines:
    """Lines a compiled core may drive: the STEP/DIR and end-stop line requests of a
    :class:`StepIO` as kernel GPIO character-device requests, written and read with ioctls,
    no Python per step. ``step[m]``/``dir[m]``: motor m's line as (index into ``outputs``,
    index of the line in that request); ``inputs``: edge-event requests, ``input_lines[i]``
    their lines' :class:`EdgeInputs` numbers in request order; ``active_low`` per input
    line. The requests stay the backend's: it releases them when the StepIO closes."""

    outputs: tuple[ChardevRequest, ...]
    step: tuple[tuple[int, int], ...]
    dir: tuple[tuple[int, int], ...]
    inputs: tuple[ChardevRequest, ...] = ()
    input_lines: tuple[tuple[int, ...], ...] = ()
    active_low: tuple[bool, ...] = ()


@dataclass(frozen=True)
class SimulatedLines:
    """Lines a compiled core may drive, of a simulated machine (the mock backend): its
    mechanics' cells (seven int64 per axis: position, heading, forced min end stop, forced
    max, forced stall, generation, pushed against a hard stop;
    :class:`~motorctl.hal.backends.mock.world.MockAxis`), where each axis' end stops sit and
    whether they have switches, the axis of each motor, and where the edges go: ``record`` takes
    them as (t ns, kind 0 step / 1 dir, axis, value, rise call) into the machine's timeline;
    ``line_errors`` gives the writes that fail now, (``"step"``/``"dir"``, axis) -> the
    HalIOError text. The compiled counterpart records the same timeline as the Python parts."""

    cells: memoryview
    endstops: tuple[tuple[int, int], ...]
    switches: tuple[bool, ...]
    axis_of: tuple[int, ...]
    timeline_len: int | None
    record: Callable[[list[tuple[int, int, int, int, int]]], None]
    line_errors: Callable[[], dict[tuple[str, int], str]]


#: What a backend's StepIO offers a compiled step core (``StepIO.compiled``)
CompiledLines = ChardevLines | SimulatedLines
