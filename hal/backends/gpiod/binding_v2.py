"""libgpiod's v2 Python binding (PyPI gpiod >= 2, Debian 13 / Raspberry Pi OS trixie
python3-libgpiod 2.x) behind :class:`~motorctl.hal.backends.gpiod.chip.GpioApi`. Made by
:func:`~motorctl.hal.backends.gpiod.chip.load_api`, which imports ``gpiod`` and hands it over.

Threads: as chip.py: a request belongs to the part that made it; that part's owner calls it.
"""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from motorctl.hal.backends.gpiod.chip import (
    ChipInfo,
    Edge,
    GpioApi,
    LineInfo,
    LineRequest,
    LineSettings,
    chardev_request,
)
from motorctl.hal.compiled_lines import ChardevRequest


class V2Api(GpioApi):
    def __init__(self, gpiod: Any) -> None:
        self.g = gpiod
        self.name = "v2"
        self.version = str(getattr(gpiod, "__version__", "2"))
        from gpiod import line

        self.line = line

    def chip_info(self, path: str) -> ChipInfo:
        with self.g.Chip(path) as chip:
            info = chip.get_info()
            return ChipInfo(path, info.name, info.label, info.num_lines)

    def line_names(self, path: str) -> list[str]:
        with self.g.Chip(path) as chip:
            n = chip.get_info().num_lines
            return [chip.get_line_info(off).name or "" for off in range(n)]

    def line_info(self, path: str, offset: int) -> LineInfo:
        with self.g.Chip(path) as chip:
            i = chip.get_line_info(offset)
            return LineInfo(
                offset,
                i.name or "",
                i.used,
                i.consumer or "",
                i.direction == self.line.Direction.OUTPUT,
            )

    def settings(self, s: LineSettings) -> Any:
        L = self.line
        bias = {
            "as-is": L.Bias.AS_IS,
            "pull-up": L.Bias.PULL_UP,
            "pull-down": L.Bias.PULL_DOWN,
            "disabled": L.Bias.DISABLED,
        }[s.bias]
        kw: dict[str, Any] = {"bias": bias}
        if s.output:
            kw.update(
                direction=L.Direction.OUTPUT,
                output_value=L.Value.ACTIVE if s.value else L.Value.INACTIVE,
            )
        else:
            kw["direction"] = L.Direction.INPUT
            if s.edges:
                kw["edge_detection"] = L.Edge.BOTH
                if s.debounce_us:
                    kw["debounce_period"] = timedelta(microseconds=s.debounce_us)
        return self.g.LineSettings(**kw)

    def _request(self, path: str, consumer: str, settings: dict[int, LineSettings]) -> LineRequest:
        cfg = {off: self.settings(s) for off, s in settings.items()}
        req = self.g.request_lines(path, consumer=consumer, config=cfg)
        return V2Request(self, path, settings, req)


class V2Request(LineRequest):
    def __init__(self, api: V2Api, path: str, settings: dict[int, LineSettings], req: Any) -> None:
        super().__init__(path, settings)
        self.api = api
        self.req = req
        Value = api.line.Value
        self.hi, self.lo, self.active = Value.ACTIVE, Value.INACTIVE, Value.ACTIVE
        self.rising = api.g.EdgeEvent.Type.RISING_EDGE

    def set_values(self, values: dict[int, bool]) -> None:
        hi, lo = self.hi, self.lo
        self.req.set_values({off: hi if v else lo for off, v in values.items()})

    def set_value(self, offset: int, level: bool) -> None:
        self.req.set_value(offset, self.hi if level else self.lo)

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [v == self.active for v in self.req.get_values(offsets)]

    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        self.settings[offset] = settings
        self.req.reconfigure_lines({o: self.api.settings(s) for o, s in self.settings.items()})

    def fileno(self) -> int:
        return int(self.req.fd)

    def raw(self) -> ChardevRequest | str:
        try:
            fd, offsets = int(self.req.fd), tuple(int(o) for o in self.req.offsets)
        except (AttributeError, TypeError, ValueError) as exc:
            return f"the gpiod binding gives no descriptor and offsets ({exc})"
        levels = tuple(self.settings[o].value for o in offsets if o in self.settings)
        return chardev_request(fd, offsets, levels if len(levels) == len(offsets) else ())

    def read_events(self) -> list[Edge]:
        rising = self.rising
        return [
            Edge(e.line_offset, e.event_type == rising, e.timestamp_ns)
            for e in self.req.read_edge_events()
        ]

    def release(self) -> None:
        self.req.release()
