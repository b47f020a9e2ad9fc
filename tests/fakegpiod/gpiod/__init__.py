"""A stand-in for libgpiod's Python binding (v2 API) in a motorctld subprocess on a machine
without GPIO (tests/hal/backends/gpiod/test_backend_e2e.py): put tests/fakegpiod first on
PYTHONPATH.

It lets the gpiod backend load and look for chips (the kernel's /dev/gpiochip*, as the real
binding does; none in the test container), and refuses every line request: the test's
point is that a machine whose motors' TMC5160s run their own ramps opens no GPIO line at
all. A request raises OSError naming what was asked for, which the daemon reports.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from gpiod import line

__version__ = "2.fake"
__all__ = ["Chip", "EdgeEvent", "LineSettings", "line", "request_lines"]


@dataclass
class ChipInfo:
    name: str
    label: str
    num_lines: int


class Chip:
    """A chip found under /dev: named, but without lines this stand-in could serve."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __enter__(self) -> Chip:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def get_info(self) -> ChipInfo:
        return ChipInfo(os.path.basename(self.path), "fakegpiod", 0)

    def get_line_info(self, offset: int) -> Any:
        raise OSError(f"fakegpiod: line info of {self.path}:{offset} asked for")


class EdgeEvent:
    class Type:
        RISING_EDGE = "rising"
        FALLING_EDGE = "falling"


class LineSettings:
    def __init__(self, **kw: Any) -> None:
        self.kw = kw


def request_lines(path: str, consumer: str = "", config: Any = None) -> Any:
    raise OSError(
        f"fakegpiod: {consumer!r} requested lines {sorted(config or {})} of {path}; "
        "this test allows no GPIO line"
    )
