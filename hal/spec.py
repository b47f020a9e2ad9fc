"""What a backend is asked to build: plain data, no config-file parsing.

``sections`` carry the backend's own config sections as loaded (the dataclasses its config
module declares, see hal/registry.py): a backend reads them with ``spec.section(Cls)``,
``spec.axes[i].section(Cls)`` and ``spec.pins[i].section(Cls)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from motorctl.schema import Sectioned

if TYPE_CHECKING:
    from motorctl.hal.tmc import TmcSpec


@dataclass(frozen=True)
class AxisSpec(Sectioned):
    """One stepper axis. ``endstop_min``/``endstop_max`` place the mock's simulated end stops."""

    invert_dir: bool = False
    endstop_active_low: bool = False
    endstop_min: int = -10_000
    endstop_max: int = 10_000
    debounce_s: float = 0.0
    name: str = ""
    driver: TmcSpec | None = None  # a TMC2130/TMC5160 on SPI; None: no driver to talk to
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [motors.<backend>]


@dataclass(frozen=True)
class PinSpec(Sectioned):
    number: int
    output: bool
    initial: bool = False
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [pins.<backend>]


@dataclass(frozen=True)
class HardwareSpec(Sectioned):
    axes: tuple[AxisSpec, ...]
    pins: tuple[PinSpec, ...] = ()
    dc: bool = False
    wires: tuple[tuple[int, int], ...] = ()
    options: dict[str, object] = field(default_factory=dict)
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [<backend>]
