"""What a backend is asked to build: plain data, no config-file knowledge."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from motorctl.hal.tmc import TmcSpec


@dataclass(frozen=True)
class AxisSpec:
    """One stepper axis. ``endstop_min``/``endstop_max`` place the mock's simulated end stops."""

    invert_dir: bool = False
    endstop_active_low: bool = False
    endstop_min: int = -10_000
    endstop_max: int = 10_000
    name: str = ""
    driver: TmcSpec | None = None  # a TMC2130/TMC5160 on SPI; None: no driver to talk to


@dataclass(frozen=True)
class PinSpec:
    number: int
    output: bool
    initial: bool = False


@dataclass(frozen=True)
class HardwareSpec:
    axes: tuple[AxisSpec, ...]
    pins: tuple[PinSpec, ...] = ()
    dc: bool = False
    wires: tuple[tuple[int, int], ...] = ()
    options: dict[str, object] = field(default_factory=dict)
