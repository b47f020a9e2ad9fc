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
from typing import TYPE_CHECKING, Any

from motorctl.schema import Sectioned

if TYPE_CHECKING:
    from motorctl.hal.backends.tmc.settings import TmcSpec


@dataclass(frozen=True)
class AxisSpec(Sectioned):
    """One stepper axis.

    ``wiring`` names the lines by role as the backend understands them, e.g.
    ``(("step", "gpiochip0:17"), ("dir", "GPIO27"), ("min", "gpiochip0:5"))``; roles:
    step, dir, enable, min, max. ``endstop_active_low`` is the end stops' polarity (backends
    report logical levels). ``dir_setup_s``/``dir_hold_s``: DIR must be stable this long
    before a STEP rise / after a STEP fall. ``endstop_min``/``endstop_max`` place the mock's
    simulated end stops (the mock only).
    """

    invert_dir: bool = False
    endstop_active_low: bool = False
    endstop_min: int = -10_000
    endstop_max: int = 10_000
    name: str = ""
    driver: TmcSpec | None = None  # a TMC2130/TMC5160 on SPI; None: no driver to talk to
    wiring: tuple[tuple[str, str], ...] = ()
    dir_setup_s: float = 5e-6
    dir_hold_s: float = 0.0
    endstop_debounce_s: float = 0.0
    sections: Mapping[type[Any], Any] = field(default_factory=dict)  # [motors.<backend>]

    @property
    def own_ramp(self) -> bool:
        """Its TMC5160 runs its own ramp: no STEP/DIR, not the step executor's."""
        return self.driver is not None and self.driver.ramp

    def line(self, role: str) -> str | None:
        for r, name in self.wiring:
            if r == role:
                return name
        return None


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

    def stepped(self) -> tuple[int, ...]:
        """The axes a step executor drives (all but those whose TMC5160 runs its own ramp),
        in order: a StepIO's motor ``j`` is axis ``stepped()[j]``."""
        return tuple(i for i, a in enumerate(self.axes) if not a.own_ramp)
