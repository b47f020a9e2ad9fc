"""A start's timeline: when each step of motorctld's start-up ended, on the monotonic clock.

daemon/start/main.py makes one for a command line that serves (its first mark: the daemon's
modules imported); daemon/start/serve.py and the assembler mark each step as it ends (the config
read, the hardware opened, the step executor's process handed its parameters, the state
restored, the PTY, the link, the status socket, the executor ready, the threads started,
READY). At READY daemon/start/serve.py logs it in one line at debug level::

    start-up: imported at 81234.567890 s (monotonic); arguments 0.4 ms, config 6.1 ms, ...

each step's own time after the one before it. ``bench/startup.py`` reads that line for its
breakdown (the time before the first mark, the interpreter's start and the imports, it
measures from its own clock: the same monotonic clock). Reading a clock is all it costs.

Owner: the main thread, during the start only.
"""

from __future__ import annotations

import time
from collections.abc import Callable

#: how the line starts (bench/startup.py looks for it)
PREFIX = "start-up: "


class StartTimeline:
    """The steps of one start and when each ended (``clock``: seconds, monotonic)."""

    def __init__(self, first: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.marks: list[tuple[str, float]] = [(first, clock())]

    def mark(self, step: str) -> None:
        """``step`` has just ended."""
        self.marks.append((step, self.clock()))

    def steps_ms(self) -> list[tuple[str, float]]:
        """Each step after the first mark with its own time in ms (since the mark before)."""
        return [
            (step, (t - before) * 1000)
            for (_, before), (step, t) in zip(self.marks, self.marks[1:], strict=False)
        ]

    def text(self) -> str:
        """The line logged at READY (see the module's doc)."""
        first, at = self.marks[0]
        steps = ", ".join(f"{step} {ms:.1f} ms" for step, ms in self.steps_ms())
        return f"{PREFIX}{first} at {at:.6f} s (monotonic); {steps}"


def parse(line: str) -> tuple[str, float, list[tuple[str, float]]] | None:
    """A :meth:`StartTimeline.text` line (anywhere in ``line``) back as (first step, its
    monotonic time in s, [(step, ms)]); None when ``line`` holds none."""
    start = line.find(PREFIX)
    if start < 0:
        return None
    head, _, rest = line[start + len(PREFIX) :].partition(" s (monotonic); ")
    first, _, at = head.rpartition(" at ")
    try:
        steps = []
        for part in rest.strip().split(", ") if rest.strip() else []:
            step, _, ms = part.removesuffix(" ms").rpartition(" ")
            steps.append((step, float(ms)))
        return first, float(at), steps
    except ValueError:
        return None
