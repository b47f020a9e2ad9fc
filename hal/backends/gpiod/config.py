"""The gpiod backend's declaration (:class:`GpiodDeclaration`, hal/contract.py): its config
sections [gpiod] (binding, consumer, the H-bridge's lines), [motors.gpiod] (a motor's
STEP/DIR/ENABLE and end-stop lines) and [pins.gpiod] (a pin's line).

A motor whose driver chip runs its own ramp (a TMC5160 with ``[motors.tmc] mode = "ramp"``:
``AxisSpec.own_ramp``, from the driver spec its layer gives it) needs no STEP/DIR lines (the
chip makes its own steps; its end stops are the chip's REFL/REFR inputs): its [motors.gpiod]
is optional, and so are step and dir in it; every other motor must name both.

Named in `motorctl.hal.registry.BACKENDS`; imports no hardware library, so a config can be
checked on any machine. `wiring_from` turns the loaded sections into the backend's
`GpioWiring`; the rule below checks, before anything opens, that every motor and pin is
wired and that no line is written twice.

Pure declarations and functions: no state, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar, cast

from motorctl.hal.backends.gpiod.wiring import (
    AS_IS,
    BIASES,
    BRIDGE_STOPS,
    DcWiring,
    EndstopWiring,
    GpioWiring,
    LineRef,
    MotorWiring,
    PinWiring,
    PwmWiring,
)
from motorctl.hal.contract import BackendDeclaration, DriverLookup
from motorctl.hal.interfaces import HalError
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.schema import (
    REQUIRED,
    Extension,
    Parser,
    Rule,
    Violation,
    boolean,
    choice,
    integer,
    number,
    section,
    table,
    table_of,
    text,
)

S = TypeVar("S")

LINE_TEXT = 'a GPIO line: "chip:offset" (gpiochip0:17, /dev/gpiochip0:17) or a line name (GPIO17)'


def _line(value: str) -> str | None:
    try:
        LineRef.parse(value)
    except ValueError:
        return "not a GPIO line"
    return None


def _line_or_empty(value: str) -> str | None:
    return None if value == "" else _line(value)


def _line_key(default: Any, doc: str) -> Any:
    if default == "":
        return text("", doc, check=_line_or_empty, check_text=f'"" (not wired) or {LINE_TEXT}')
    return text(default, doc, check=_line, check_text=LINE_TEXT)


@section("A kernel PWM channel on the bridge's EN input (sysfs), instead of an EN line.")
@dataclass(frozen=True)
class GpiodPwmConfig:
    """[gpiod.dc.pwm]"""

    chip: int = integer(REQUIRED, 0, 255, "N of /sys/class/pwm/pwmchipN.")
    channel: int = integer(REQUIRED, 0, 255, "M of pwmchipN/pwmM.")
    period_ns: int = integer(
        PwmWiring.period_ns, 1_000, 1_000_000_000, "PWM period in ns (50000 = 20 kHz)."
    )
    duty: float = number(PwmWiring.duty, 0.0, 1.0, "Duty cycle while the motor runs (the speed).")
    sysfs: str = text(PwmWiring.sysfs, "Where the kernel's PWM class is.")


@section(
    "The DC motor's H-bridge lines.",
    notes="""\
FORWARD drives IN1 high and IN2 low, REVERSE the opposite; BRAKE drives both high (EN high),
COAST both low and EN low where EN is wired. A DcMove that reverses a running motor first
holds `reverse_via` for `dead_time_ms`.""",
)
@dataclass(frozen=True)
class GpiodDcConfig:
    """[gpiod.dc]"""

    in1: str = _line_key(REQUIRED, "The bridge's IN1 line.")
    in2: str = _line_key(REQUIRED, "The bridge's IN2 line.")
    en: str = _line_key("", "The bridge's EN line; empty: not wired (EN tied high).")
    dead_time_ms: float = number(
        DcWiring.dead_time_ms, 0, 10_000, "A reversal passes through reverse_via this long."
    )
    reverse_via: str = choice(
        DcWiring.reverse_via, BRIDGE_STOPS, "The state a reversal passes through."
    )
    pwm: GpiodPwmConfig | None = table(GpiodPwmConfig, absent=None, absent_text="no PWM")


@section(
    "The gpiod backend: real GPIO lines through libgpiod (docs/hardware.md).",
    notes="""\
A line is written as the kernel names it: `gpiochip0:17` (chip and offset; the chip may
also be `/dev/gpiochip0` or its label) or a line name such as `GPIO17` that `gpioinfo`
shows, looked up across all chips. Every line is checked before any is requested: a line
written twice, a missing chip or line, a line held by another program (named) and a
permission problem (with the group to join) are errors.""",
)
@dataclass(frozen=True)
class GpiodConfig:
    """[gpiod]"""

    api: str = choice(
        GpioWiring.api,
        ("auto", "v1", "v2"),
        "libgpiod Python API: v1 (Debian bookworm "
        "python3-libgpiod 1.6), v2 (gpiod >= 2), or auto: whichever imports.",
    )
    consumer: str = text(
        GpioWiring.consumer,
        "The consumer name the kernel shows for our lines.",
        pattern=r"[!-~]{1,31}",
        pattern_text="1..31 characters, no spaces",
    )
    dc: GpiodDcConfig | None = table(GpiodDcConfig, absent=None, absent_text="no bridge wired")


@section(
    "The lines of one motor for the gpiod backend.",
    notes="""\
`step` and `dir` are required, except for a motor whose TMC5160 runs its own ramp
(`[motors.tmc] mode = "ramp"`): the chip makes its own steps, so leave them out (the whole
[motors.gpiod] too when nothing else is wired) where the chip's STEP/DIR pins are tied off or
serve as its DIAG outputs; if named, they are only held low (and `enable` on) while the
daemon runs, never stepped. Such a motor's end stops are the chip's REFL/REFR inputs, so it
takes no endstop_min/endstop_max.""",
)
@dataclass(frozen=True)
class GpiodAxisConfig:
    """[motors.gpiod]"""

    step: str = _line_key(
        "", "The driver's STEP line; empty: not wired (only for a TMC5160 running its own ramp)."
    )
    dir: str = _line_key("", "The driver's DIR line; empty: not wired (as step).")
    enable: str = _line_key(
        "", "The driver's ENABLE line (on while the daemon runs); empty: not wired."
    )
    enable_active_low: bool = boolean(
        MotorWiring.enable_active_low, "ENABLE is active low (TMC drivers: EN low = on)."
    )
    dir_hold_us: float = number(
        MotorWiring.dir_hold_us, 0, 10_000, "DIR stays this long after a STEP falls."
    )
    endstop_min: str = _line_key(
        "",
        "End stop below (InitMove with DIR false); empty: none. "
        "Polarity: [motors.endstop] active_low.",
    )
    endstop_min_bias: str = choice(AS_IS, BIASES, "Pull on the endstop_min line.")
    endstop_max: str = _line_key("", "End stop above; empty: none.")
    endstop_max_bias: str = choice(AS_IS, BIASES, "Pull on the endstop_max line.")


@section("The line of one pin for the gpiod backend.")
@dataclass(frozen=True)
class GpiodPinConfig:
    """[pins.gpiod]"""

    line: str = _line_key(REQUIRED, "The pin's line.")
    bias: str = choice(AS_IS, BIASES, "Pull on the line.")


def make(cls: type[S], **keys: Any) -> S:
    """A section built from these keys as the config loader builds it (defaults filled in,
    values checked): for code and tests that wire lines without a file."""
    return cast(S, Parser(f"[{cls.__name__}]").build(table_of(cls), keys))


class WiringMissing(ValueError):
    """A motor, pin or the bridge is not wired as it must be: (key path, problem, value)."""

    def __init__(self, path: str, problem: str, value: Any = REQUIRED) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem
        self.value = value


def _motor(i: int, axis: AxisSpec) -> str:
    return f"motor {i} ({axis.name!r})" if axis.name else f"motor {i}"


_RAMP_NOTE = (
    'only a TMC5160 that runs its own ramp ([motors.tmc] driver = "tmc5160", '
    'mode = "ramp") goes without'
)


def _axis_wiring(i: int, a: GpiodAxisConfig | None, axis: AxisSpec) -> MotorWiring:
    if a is None:
        if axis.own_ramp:
            return MotorWiring(own_ramp=True)
        raise WiringMissing(
            f"motors[{i}].gpiod",
            f"missing: {_motor(i, axis)} is moved by "
            f"STEP/DIR pulses; name its step and dir lines ({_RAMP_NOTE})",
        )
    for key in ("step", "dir"):
        if not axis.own_ramp and not getattr(a, key):
            raise WiringMissing(
                f"motors[{i}].gpiod.{key}",
                f"missing: {_motor(i, axis)} is "
                f"moved by STEP/DIR pulses and needs its {key.upper()} line "
                f"({_RAMP_NOTE})",
            )
    if axis.own_ramp:
        for key in ("endstop_min", "endstop_max"):
            if getattr(a, key):
                raise WiringMissing(
                    f"motors[{i}].gpiod.{key}",
                    f"{_motor(i, axis)}'s TMC5160 "
                    "runs its own ramp and stops at its REFL/REFR inputs, "
                    "which no GPIO line can stand for: remove it",
                    getattr(a, key),
                )

    def end(line: str, bias: str) -> EndstopWiring | None:
        return EndstopWiring(LineRef.parse(line), bias) if line else None

    def line(text_: str) -> LineRef | None:
        return LineRef.parse(text_) if text_ else None

    return MotorWiring(
        step=line(a.step),
        dir=line(a.dir),
        enable=line(a.enable),
        enable_active_low=a.enable_active_low,
        endstop_min=end(a.endstop_min, a.endstop_min_bias),
        endstop_max=end(a.endstop_max, a.endstop_max_bias),
        dir_hold_us=a.dir_hold_us,
        own_ramp=axis.own_ramp,
    )


def wiring_from(
    top: GpiodConfig | None,
    sections: Sequence[GpiodAxisConfig | None],
    pins: Sequence[tuple[int, GpiodPinConfig | None]],
    dc: bool,
    axes: Sequence[AxisSpec] | None = None,
) -> GpioWiring:
    """The backend's wiring from the loaded sections (``sections``: each motor's
    [motors.gpiod]); ``axes`` (default: every motor moved by STEP/DIR) name the motors and
    say whose driver chip runs its own ramp (``AxisSpec.own_ramp``)."""
    top = top or make(GpiodConfig)
    axes = list(axes) if axes is not None else [AxisSpec() for _ in sections]
    motors = [
        _axis_wiring(i, a, axis) for i, (a, axis) in enumerate(zip(sections, axes, strict=True))
    ]
    wired = []
    for i, (number_, p) in enumerate(pins):
        if p is None:
            raise WiringMissing(
                f"pins[{i}].gpiod", "missing: the gpiod backend needs the pin's line"
            )
        wired.append(PinWiring(number_, LineRef.parse(p.line), p.bias))
    bridge = None
    if dc:
        d = top.dc
        if d is None:
            raise WiringMissing(
                "gpiod.dc", "missing: [dc] configures a DC motor; wire its bridge in [gpiod.dc]"
            )
        pwm = (
            None
            if d.pwm is None
            else PwmWiring(d.pwm.chip, d.pwm.channel, d.pwm.period_ns, d.pwm.duty, d.pwm.sysfs)
        )
        bridge = DcWiring(
            LineRef.parse(d.in1),
            LineRef.parse(d.in2),
            LineRef.parse(d.en) if d.en else None,
            d.dead_time_ms,
            d.reverse_via,
            pwm,
        )
    return GpioWiring(
        api=top.api, consumer=top.consumer, motors=tuple(motors), dc=bridge, pins=tuple(wired)
    )


def wiring_of(spec: HardwareSpec) -> GpioWiring:
    """The wiring from the config sections ([gpiod], [motors.gpiod], [pins.gpiod])."""
    try:
        return wiring_from(
            spec.sections.get(GpiodConfig),
            [a.sections.get(GpiodAxisConfig) for a in spec.axes],
            [(p.number, p.sections.get(GpiodPinConfig)) for p in spec.pins],
            spec.dc,
            spec.axes,
        )
    except WiringMissing as exc:
        raise HalError(str(exc)) from None


def _wired(drivers: DriverLookup) -> Callable[[Mapping[str, Any]], Violation | None]:
    """The rule: with backend gpiod, every motor and pin wired, the bridge too, no line
    twice; ``drivers`` gives each motor's driver chip (one that runs its own ramp needs no
    STEP/DIR)."""

    def wired(v: Mapping[str, Any]) -> Violation | None:
        if v["hal"].backend != "gpiod":
            return None
        try:
            wiring = wiring_from(
                v.get("gpiod"),
                [m.sections.get(GpiodAxisConfig) for m in v["motors"]],
                [(p.number, p.sections.get(GpiodPinConfig)) for p in v["pins"]],
                v["dc"] is not None,
                [AxisSpec(name=m.name, driver=drivers(m)) for m in v["motors"]],
            )
        except WiringMissing as exc:
            return (exc.path, exc.value, exc.problem)
        dup = wiring.duplicates()
        if dup:
            return ("gpiod", REQUIRED, dup[0])
        return None

    return wired


class GpiodDeclaration(BackendDeclaration):
    """The gpiod backend's sections: ``[gpiod]``, ``[motors.gpiod]``, ``[pins.gpiod]``."""

    def sections(self, drivers: DriverLookup) -> tuple[Extension, ...]:
        return (
            Extension(
                "",
                "gpiod",
                GpiodConfig,
                owner="the gpiod backend",
                absent=None,
                absent_text="defaults (api auto, consumer motorctl, no bridge)",
                rules=(
                    Rule(
                        ("gpiod",),
                        'with backend "gpiod": every motor (STEP/DIR; a TMC5160 running its '
                        "own ramp: none needed), pin and the DC bridge wired, each line used "
                        "once",
                        _wired(drivers),
                    ),
                ),
            ),
            Extension(
                "motors",
                "gpiod",
                GpiodAxisConfig,
                owner="the gpiod backend",
                absent=None,
                absent_text="not wired",
            ),
            Extension(
                "pins",
                "gpiod",
                GpiodPinConfig,
                owner="the gpiod backend",
                absent=None,
                absent_text="not wired",
            ),
        )
