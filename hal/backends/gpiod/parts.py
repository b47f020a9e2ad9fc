"""The gpiod backend's parts on line requests: a user pin, the step executor's STEP/DIR
outputs and end-stop edge inputs, and the driver of a motor without a status channel.

Threads: the step executor's thread owns the step outputs and edge inputs; the link thread
owns the pins. Calls block only on GPIO ioctls or a step pulse's busy-wait; run-time
failures on the step path raise HalIOError.
"""

from __future__ import annotations

from collections.abc import Sequence

from motorctl.hal.backends.gpiod.chip import LineRequest, LineSettings
from motorctl.hal.backends.gpiod.wiring import MotorWiring
from motorctl.hal.interfaces import (
    Clock,
    DriverStatus,
    Edge,
    EdgeInputs,
    HalIOError,
    Pin,
    StepOutputs,
    StepperDriver,
)
from motorctl.hal.spec import AxisSpec


class GpiodPin(Pin):
    """A user pin on its own single-line request."""

    def __init__(
        self, number: int, req: LineRequest, offset: int, output: bool, level: bool, bias: str
    ) -> None:
        super().__init__(number, output, level)
        self.req = req
        self.offset = offset
        self.bias = bias

    def _configure(self, output: bool, level: bool) -> None:
        self.req.reconfigure(self.offset, LineSettings(output=output, value=level, bias=self.bias))

    def _write(self, level: bool) -> None:
        self.req.set_values({self.offset: level})

    def _read(self) -> bool:
        return self.req.get_values([self.offset])[0]


class GpiodStepOutputs(StepOutputs):
    """STEP/DIR of every stepped motor (``spec.stepped()``): one request per chip holding all
    their STEP, DIR (and ENABLE) lines on it, so several STEP lines go out in one
    ``set_values`` call."""

    def __init__(
        self,
        clock: Clock,
        motors: Sequence[tuple[MotorWiring, AxisSpec]],
        reqs: list[LineRequest],
        steps: list[tuple[int, int]],
        dirs: list[tuple[int, int]],
    ) -> None:
        super().__init__(
            clock,
            [a.invert_dir for _, a in motors],
            [a.dir_setup_s for _, a in motors],
            [max(m.dir_hold_us / 1e6, a.dir_hold_s) for m, a in motors],
        )
        self.reqs = reqs
        self.steps = steps  # motor -> (request index, STEP offset)
        self.dirs = dirs  # motor -> (request index, DIR offset)

    def _write_dir(self, motor: int, level: bool) -> None:
        r, off = self.dirs[motor]
        try:
            self.reqs[r].set_values({off: level})
        except OSError as exc:
            raise HalIOError(f"motor {motor}: DIR write failed: {exc}") from exc

    def _write_steps(self, motors: Sequence[int], level: bool) -> None:
        steps = self.steps
        try:
            if len(self.reqs) == 1:
                self.reqs[0].set_values({steps[m][1]: level for m in motors})
                return
            by_req: dict[int, dict[int, bool]] = {}
            for m in motors:
                r, off = steps[m]
                by_req.setdefault(r, {})[off] = level
            for r, values in by_req.items():
                self.reqs[r].set_values(values)
        except OSError as exc:
            raise HalIOError(f"motors {list(motors)}: STEP write failed: {exc}") from exc


class GpiodEdgeInputs(EdgeInputs):
    """End stops as kernel edge events (CLOCK_MONOTONIC timestamps); never polled per step.

    On v2 the end stops of one chip share one request (and the kernel debounces); v1 has one
    request per line. ``fileno`` is the request's descriptor when there is one request.
    """

    def __init__(
        self,
        names: list[str],
        reqs: list[LineRequest],
        index: dict[tuple[int, int], int],
        active_low: list[bool],
    ) -> None:
        super().__init__(names)
        self.reqs = reqs
        self.index = index  # (request, offset) -> line
        self.active_low = active_low
        self.levels = [False] * len(names)
        for (r, off), line in index.items():
            self.levels[line] = reqs[r].get_values([off])[0] != active_low[line]

    def read_edges(self) -> list[Edge]:
        out: list[Edge] = []
        try:
            for r, req in enumerate(self.reqs):
                for e in req.wait_events(0.0):
                    line = self.index[(r, e.offset)]
                    active = e.rising != self.active_low[line]
                    self.levels[line] = active
                    out.append(Edge(line, active, e.timestamp_ns / 1e9))
        except OSError as exc:
            raise HalIOError(f"end stops: reading edge events failed: {exc}") from exc
        out.sort(key=lambda e: e.t)
        return out

    def level(self, line: int) -> bool:
        return self.levels[line]

    def fileno(self) -> int | None:
        return self.reqs[0].fileno() if len(self.reqs) == 1 else None


class NoDriver(StepperDriver):
    """A driver without a status channel (step/dir only): always healthy."""

    def status(self) -> DriverStatus:
        return DriverStatus()
