"""libgpiod's v1 Python binding (1.6: Debian 12 / Raspberry Pi OS bookworm python3-libgpiod)
behind :class:`~motorctl.hal.backends.gpiod.chip.GpioApi`. Made by
:func:`~motorctl.hal.backends.gpiod.chip.load_api`, which imports ``gpiod`` and hands it over.

Threads: as chip.py: a request belongs to the part that made it; that part's owner calls it.
"""

from __future__ import annotations

import os
import select
from typing import Any

from motorctl.hal.backends.gpiod.chip import (
    ChipInfo,
    Edge,
    GpioApi,
    LineInfo,
    LineRequest,
    LineSettings,
    chardev_request,
    fd_kind,
)
from motorctl.hal.compiled_lines import ChardevRequest
from motorctl.hal.interfaces import HalError


def _open_fds() -> dict[int, str]:
    """Open descriptors and what each is (the listing's own descriptor shows as gone: a
    later descriptor of that number is new)."""
    try:
        return {int(n): fd_kind(int(n)) for n in os.listdir("/proc/self/fd")}
    except OSError:
        return {}


class V1Api(GpioApi):
    def __init__(self, gpiod: Any) -> None:
        self.g = gpiod
        self.name = "v1"
        self.version = str(getattr(gpiod, "__version__", "1"))

    def _chip(self, path: str) -> Any:
        return self.g.Chip(path)

    def chip_info(self, path: str) -> ChipInfo:
        chip = self._chip(path)
        try:
            return ChipInfo(path, chip.name(), chip.label(), chip.num_lines())
        finally:
            chip.close()

    def line_names(self, path: str) -> list[str]:
        chip = self._chip(path)
        try:
            return [chip.get_line(off).name() or "" for off in range(chip.num_lines())]
        finally:
            chip.close()

    def line_info(self, path: str, offset: int) -> LineInfo:
        chip = self._chip(path)
        try:
            ln = chip.get_line(offset)
            return LineInfo(
                offset,
                ln.name() or "",
                ln.is_used(),
                ln.consumer() or "",
                ln.direction() == self.g.Line.DIRECTION_OUTPUT,
            )
        finally:
            chip.close()

    def flags(self, s: LineSettings) -> int:
        g = self.g
        flags: dict[str, int] = {
            "as-is": 0,
            "pull-up": g.LINE_REQ_FLAG_BIAS_PULL_UP,
            "pull-down": g.LINE_REQ_FLAG_BIAS_PULL_DOWN,
            "disabled": g.LINE_REQ_FLAG_BIAS_DISABLE,
        }
        return flags[s.bias]

    def request_one(self, chip: Any, consumer: str, offset: int, s: LineSettings) -> Any:
        g = self.g
        ln = chip.get_line(offset)
        if s.output:
            ln.request(
                consumer=consumer,
                type=g.LINE_REQ_DIR_OUT,
                flags=self.flags(s),
                default_val=int(s.value),
            )
        else:
            kind = g.LINE_REQ_EV_BOTH_EDGES if s.edges else g.LINE_REQ_DIR_IN
            ln.request(consumer=consumer, type=kind, flags=self.flags(s))
        return ln

    def _request(self, path: str, consumer: str, settings: dict[int, LineSettings]) -> LineRequest:
        chip = self._chip(path)
        try:
            if any(s.edges for s in settings.values()) or len(settings) == 1:
                # v1 event requests are per line: one line (end stops, pins) per request.
                if len(settings) != 1:
                    raise HalError("v1: an edge-event request holds one line")
                ((off, s),) = settings.items()
                return V1Request(
                    self,
                    path,
                    settings,
                    chip,
                    {off: self.request_one(chip, consumer, off, s)},
                    None,
                )
            offs = list(settings)
            g = self.g
            if not all(settings[o].output for o in offs):
                raise HalError("v1: a multi-line request is outputs only")
            bulk = chip.get_lines(offs)
            before = _open_fds()
            bulk.request(
                consumer=consumer,
                type=g.LINE_REQ_DIR_OUT,
                default_vals=[int(settings[o].value) for o in offs],
            )
            lines = {o: ln for o, ln in zip(offs, bulk.to_list(), strict=True)}
            req = V1Request(self, path, settings, chip, lines, bulk)
            # libgpiod 1.6's binding does not give an output handle's descriptor: it is the
            # one GPIO line handle this request opened (a compiled core writes it)
            handle = "anon_inode:gpio-linehandle"
            new = [fd for fd, kind in _open_fds().items() if kind == handle != before.get(fd)]
            req.handle_fd = new[0] if len(new) == 1 else None
            return req
        except BaseException:
            chip.close()
            raise


class V1Request(LineRequest):
    """v1 line handles. A multi-line handle sets all its lines at once (the v1 uAPI), so the
    driven levels of all of them are kept here and always written together."""

    def __init__(
        self,
        api: V1Api,
        path: str,
        settings: dict[int, LineSettings],
        chip: Any,
        lines: dict[int, Any],
        bulk: Any,
    ) -> None:
        super().__init__(path, settings)
        self.api = api
        self.chip = chip
        self.lines = lines
        self.bulk = bulk
        self.levels = {o: s.value for o, s in settings.items()}
        self.order = list(lines)
        self.consumer = ""
        self.handle_fd: int | None = None  # a multi-line output handle's, when found

    def set_values(self, values: dict[int, bool]) -> None:
        self.levels.update(values)
        if self.bulk is not None:
            levels = self.levels
            self.bulk.set_values([int(levels[o]) for o in self.order])
        else:
            for o, v in values.items():
                self.lines[o].set_value(int(v))

    def set_value(self, offset: int, level: bool) -> None:
        self.set_values({offset: level})

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [bool(self.lines[o].get_value()) for o in offsets]

    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        # v1 has no reconfigure in the uAPI we rely on: release and request again.
        if self.bulk is not None:
            raise HalError("v1: reconfigure is for single-line requests")
        line = self.lines[offset]
        consumer = line.consumer() or "motorctl"
        line.release()
        self.settings[offset] = settings
        self.levels[offset] = settings.value
        self.lines[offset] = self.api.request_one(self.chip, consumer, offset, settings)

    def fileno(self) -> int:
        (line,) = self.lines.values()
        return int(line.event_get_fd())

    def raw(self) -> ChardevRequest | str:
        if self.bulk is not None:
            if self.handle_fd is None:
                return "the line handle's descriptor was not found (libgpiod v1)"
            levels = tuple(self.levels[o] for o in self.order)
            return chardev_request(self.handle_fd, tuple(self.order), levels)
        ((off, line),) = self.lines.items()
        if not self.settings[off].edges:
            return "a single v1 output line gives no descriptor"
        return chardev_request(int(line.event_get_fd()), (off,))

    def read_events(self) -> list[Edge]:
        ((off, line),) = self.lines.items()
        rising = self.api.g.LineEvent.RISING_EDGE
        out: list[Edge] = []
        while True:
            r, _, _ = select.select([line.event_get_fd()], [], [], 0)
            if not r:
                return out
            ev = line.event_read()
            ts = int(ev.sec) * 1_000_000_000 + int(ev.nsec)
            out.append(Edge(off, ev.type == rising, ts))

    def release(self) -> None:
        try:
            if self.bulk is not None:
                self.bulk.release()
            else:
                for line in self.lines.values():
                    line.release()
        finally:
            self.chip.close()
