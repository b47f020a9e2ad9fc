"""What a backend is asked to build: plain data, no config-file knowledge."""

from __future__ import annotations

from dataclasses import dataclass, field

from motorctl.hal.wiring import GpioWiring


@dataclass(frozen=True)
class AxisSpec:
    """One stepper axis. ``endstop_min``/``endstop_max`` place the mock's simulated end stops."""

    invert_dir: bool = False
    endstop_active_low: bool = False
    endstop_min: int = -10_000
    endstop_max: int = 10_000
    debounce_s: float = 0.0


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
    #: the gpiod backend's wiring ([gpiod] in the config), if configured
    gpio: GpioWiring | None = None
