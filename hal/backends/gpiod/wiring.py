"""GPIO wiring: which kernel line each motor, end stop, H-bridge input and user pin is on.

Plain data and pure checks, no hardware library: the config layer parses a ``[gpiod]``
table into :class:`GpioWiring` (and reports mistakes such as a line used twice before
anything is opened); the gpiod backend resolves the :class:`LineRef` values against the
chips the kernel has. The records' defaults are the [gpiod] keys' defaults: config.py declares
each key with the default written here. Immutable values: any thread may read them.

A line is written the way the kernel names it: ``gpiochip0:17`` (chip and offset; the
chip may also be a path ``/dev/gpiochip0`` or a chip label such as ``pinctrl-bcm2711``)
or a line name such as ``GPIO17`` that is looked up across all chips.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from motorctl.hal.spec import AxisSpec

#: a line's bias left as the kernel has it: the default of every bias key
AS_IS: Final = "as-is"
BIASES: Final = (AS_IS, "pull-up", "pull-down", "disabled")
BRIDGE_STOPS: Final = ("coast", "brake")

# no NUL either: no chip's path or line's name holds one (the kernel's are C strings)
_CHIP_LINE = re.compile(r"^(?P<chip>[^:\s\x00]+):(?P<offset>\d+)$")
_NAME = re.compile(r"^[^:\s\x00]+$")


@dataclass(frozen=True, order=True)
class LineRef:
    """A line as written in the config: ``chip`` + ``offset``, or a line ``name``."""

    chip: str | None = None
    offset: int | None = None
    name: str | None = None

    @classmethod
    def parse(cls, text: str) -> LineRef:
        """``gpiochip0:17``, ``/dev/gpiochip0:17``, ``pinctrl-bcm2711:17`` or ``GPIO17``."""
        text = text.strip()
        m = _CHIP_LINE.match(text)
        if m:
            chip = m.group("chip")
            if chip.startswith("/dev/"):
                chip = chip[len("/dev/") :]
            return cls(chip=chip, offset=int(m.group("offset")))
        if _NAME.match(text) and not text.isdigit():
            return cls(name=text)
        raise ValueError(
            f"{text!r} is not a GPIO line: write chip:offset (gpiochip0:17) or a line name "
            "(GPIO17, as `gpioinfo` lists it)"
        )

    def __str__(self) -> str:
        if self.name is not None:
            return self.name
        return f"{self.chip}:{self.offset}"


@dataclass(frozen=True)
class EndstopWiring:
    """An end-stop input. Its polarity is the motor's ``[motors.endstop] active_low``."""

    line: LineRef
    bias: str = AS_IS


@dataclass(frozen=True)
class MotorWiring:
    """The STEP/DIR (and optional ENABLE) lines of one stepper driver, and its end stops.

    ``own_ramp``: the driver (a TMC5160) runs its own ramp: STEP/DIR are optional (held low
    by the daemon when named, never stepped) and there are no GPIO end stops.
    """

    step: LineRef | None = None
    dir: LineRef | None = None
    enable: LineRef | None = None
    enable_active_low: bool = True
    endstop_min: EndstopWiring | None = None
    endstop_max: EndstopWiring | None = None
    dir_hold_us: float = AxisSpec.dir_hold_s * 1e6
    own_ramp: bool = False


@dataclass(frozen=True)
class PwmWiring:
    """A kernel PWM channel (``/sys/class/pwm/pwmchipN/pwmM``) driving the bridge's EN input."""

    chip: int
    channel: int
    period_ns: int = 50_000
    duty: float = 1.0
    sysfs: str = "/sys/class/pwm"


@dataclass(frozen=True)
class DcWiring:
    """An H-bridge: IN1/IN2, optional EN line (or PWM), the reversal's dead time.

    FORWARD = IN1 high, IN2 low; REVERSE = IN1 low, IN2 high; BRAKE = both high (EN high);
    COAST = both low and EN low where EN is wired.
    """

    in1: LineRef
    in2: LineRef
    en: LineRef | None = None
    dead_time_ms: float = 0.0
    reverse_via: str = "coast"
    pwm: PwmWiring | None = None


@dataclass(frozen=True)
class PinWiring:
    """A user pin: the protocol's PIN_NR and its line (its mode and values are in [[pins]])."""

    number: int
    line: LineRef
    bias: str = AS_IS


@dataclass(frozen=True)
class GpioWiring:
    """The whole ``[gpiod]`` section."""

    api: str = "auto"  # "auto", "v1" or "v2"
    consumer: str = "motorctl"
    motors: tuple[MotorWiring, ...] = ()
    dc: DcWiring | None = None
    pins: tuple[PinWiring, ...] = ()

    def lines(self) -> list[tuple[str, LineRef]]:
        """Every line with what it is for, e.g. ``("motors[0].step", ref)``."""
        out: list[tuple[str, LineRef]] = []
        for i, m in enumerate(self.motors):
            for which, ref in (("step", m.step), ("dir", m.dir), ("enable", m.enable)):
                if ref is not None:
                    out.append((f"motors[{i}].{which}", ref))
            for which, es in (("endstop_min", m.endstop_min), ("endstop_max", m.endstop_max)):
                if es is not None:
                    out.append((f"motors[{i}].{which}", es.line))
        if self.dc is not None:
            out += [("dc.in1", self.dc.in1), ("dc.in2", self.dc.in2)]
            if self.dc.en is not None:
                out.append(("dc.en", self.dc.en))
        out += [(f"pins.{p.number}", p.line) for p in self.pins]
        return out

    def duplicates(self) -> list[str]:
        """Lines written the same way for two uses (one message per clash)."""
        seen: dict[LineRef, str] = {}
        problems: list[str] = []
        for use, ref in self.lines():
            if ref in seen:
                problems.append(f"line {ref} is used twice: by {seen[ref]} and by {use}")
            else:
                seen[ref] = use
        return problems


@dataclass(frozen=True)
class ResolvedLine:
    """A line found on a chip: the path to open and the offset on it."""

    use: str
    ref: LineRef
    chip_path: str
    offset: int
    chip_label: str = ""
    line_name: str = ""
