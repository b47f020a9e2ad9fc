"""What a backend is asked to build: plain, picklable data, no config-file parsing.

A :class:`HardwareSpec` crosses a process boundary unchanged: the step executor's own
process builds its step/dir/end-stop lines from it (``registry.open_step_io``).
``sections`` carry the backend's own config sections as loaded (the dataclasses its config
module declares, see hal/registry.py): a backend reads them with ``spec.section(Cls)``,
``spec.axes[i].section(Cls)`` and ``spec.pins[i].section(Cls)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from motorctl.schema import Sectioned


@dataclass(frozen=True)
class DriverSpec:
    """A driver chip a layer of the HAL talks to (the TMC layer's TMC2130/TMC5160), as the
    config gives it. The layer's own subclass carries the rest (``hal/layers/tmc``); the
    daemon gets one from :func:`motorctl.hal.registry.driver_spec` and reads only this."""

    @property
    def own_ramp(self) -> bool:
        """The chip runs its own ramp: the motor has no STEP/DIR (not a step executor's)."""
        return False

    @property
    def microsteps(self) -> int | None:
        """The microsteps per full step the chip is set to; None: the chip does not say."""
        return None

    @property
    def counter_range(self) -> tuple[int, int] | None:
        """The range of the chip's own position counter (a dSPIN's ABS_POS) where it moves
        the motor itself; None: no limit of the chip's."""
        return None


@dataclass(frozen=True)
class AxisSpec(Sectioned):
    """One stepper axis.

    ``wiring`` names the lines by role as the backend understands them, e.g.
    ``(("step", "gpiochip0:17"), ("dir", "GPIO27"), ("min", "gpiochip0:5"))``; roles:
    step, dir, enable, min, max. ``endstop_active_low`` is the end stops' polarity (backends
    report logical levels). ``dir_setup_s``/``dir_hold_s``: DIR must be stable this long
    before a STEP rise / after a STEP fall. What only one backend needs is in its own
    section (``sections``), e.g. the mock's simulated end stops.
    """

    invert_dir: bool = False
    endstop_active_low: bool = False
    name: str = ""
    driver: DriverSpec | None = None  # a driver chip a layer talks to; None: none
    wiring: tuple[tuple[str, str], ...] = ()
    dir_setup_s: float = 5e-6
    dir_hold_s: float = 0.0
    endstop_debounce_s: float = 0.0
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [motors.<backend>]

    @property
    def own_ramp(self) -> bool:
        """Its driver chip runs its own ramp: no STEP/DIR, not the step executor's."""
        return self.driver is not None and self.driver.own_ramp

    def line(self, role: str) -> str | None:
        for r, name in self.wiring:
            if r == role:
                return name
        return None


@dataclass(frozen=True)
class PinSpec(Sectioned):
    """One user GPIO pin: its number, direction and initial level, and its backend's
    section ([pins.<backend>])."""

    number: int
    output: bool
    initial: bool = False
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [pins.<backend>]


@dataclass(frozen=True)
class HardwareSpec(Sectioned):
    """The machine a backend builds: its stepper axes, user pins, whether it has the DC
    motor, the backend's options and its sections ([<backend>])."""

    axes: tuple[AxisSpec, ...]
    pins: tuple[PinSpec, ...] = ()
    dc: bool = False
    options: dict[str, object] = field(default_factory=dict)
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [<backend>]

    def stepped(self) -> tuple[int, ...]:
        """The axes a step executor drives (all but those whose driver chip runs its own
        ramp), in order: a StepIO's motor ``j`` is axis ``stepped()[j]``."""
        return tuple(i for i, a in enumerate(self.axes) if not a.own_ramp)
