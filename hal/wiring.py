"""GPIO wiring: which kernel line each motor, end stop, H-bridge input and user pin is on.

Plain data and pure checks, no hardware library: the config layer parses a ``[gpiod]``
table into :class:`GpioWiring` (and reports mistakes such as a line used twice before
anything is opened); the gpiod backend resolves the :class:`LineRef` values against the
chips the kernel has. Immutable values: any thread may read them.

A line is written the way the kernel names it: ``gpiochip0:17`` (chip and offset; the
chip may also be a path ``/dev/gpiochip0`` or a chip label such as ``pinctrl-bcm2711``)
or a line name such as ``GPIO17`` that is looked up across all chips.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Final

BIASES: Final = ("as-is", "pull-up", "pull-down", "disabled")
BRIDGE_STOPS: Final = ("coast", "brake")

_CHIP_LINE = re.compile(r"^(?P<chip>[^:\s]+):(?P<offset>\d+)$")
_NAME = re.compile(r"^[^:\s]+$")


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
                chip = chip[len("/dev/"):]
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
    bias: str = "as-is"


@dataclass(frozen=True)
class MotorWiring:
    """The STEP/DIR (and optional ENABLE) lines of one stepper driver, and its end stops."""

    step: LineRef
    dir: LineRef
    enable: LineRef | None = None
    enable_active_low: bool = True
    endstop_min: EndstopWiring | None = None
    endstop_max: EndstopWiring | None = None
    dir_hold_us: float = 0.0


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
    bias: str = "as-is"


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
            out += [(f"motors[{i}].step", m.step), (f"motors[{i}].dir", m.dir)]
            if m.enable is not None:
                out.append((f"motors[{i}].enable", m.enable))
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


@dataclass
class ProbeReport:
    """What ``motorctld --probe`` prints: sections of lines, each backend adds its own."""

    sections: list[tuple[str, list[str]]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def add(self, title: str, lines: list[str]) -> None:
        self.sections.append((title, lines))

    def text(self) -> str:
        out: list[str] = []
        for title, lines in self.sections:
            out.append(f"{title}:")
            out += [f"  {line}" for line in lines]
        for p in self.problems:
            out.append(f"PROBLEM: {p}")
        return "\n".join(out) + "\n"


# --------------------------------------------------------------------------------------------
# The [gpiod] config section (the backend owns it; the config layer hands over the table)


class WiringError(ValueError):
    """A problem in the [gpiod] table; the message starts with the key path."""


_TOP_KEYS: Final = ("api", "consumer", "motors", "dc", "pins")
_MOTOR_KEYS: Final = ("step", "dir", "enable", "enable_active_low", "dir_hold_us",
                      "endstop_min", "endstop_max")
_DC_KEYS: Final = ("in1", "in2", "en", "dead_time_ms", "reverse_via", "pwm")
_PWM_KEYS: Final = ("chip", "channel", "period_ns", "duty", "sysfs")
_LINE_KEYS: Final = ("line", "bias")


def _table(raw: object, path: str, keys: tuple[str, ...]) -> dict[str, object]:
    if not isinstance(raw, dict):
        raise WiringError(f"{path}: must be a table; accepted keys: {', '.join(keys)}")
    for k in raw:
        if k not in keys:
            raise WiringError(f"{path}.{k}: unknown key; accepted keys in {path}: "
                              f"{', '.join(keys)}")
    return raw


def _line(raw: object, path: str) -> LineRef:
    if not isinstance(raw, str):
        raise WiringError(f"{path}: must be a string such as \"gpiochip0:17\" or \"GPIO17\"")
    try:
        return LineRef.parse(raw)
    except ValueError as exc:
        raise WiringError(f"{path}: {exc}") from None


def _line_bias(raw: object, path: str) -> tuple[LineRef, str]:
    """``"GPIO5"`` or ``{ line = "GPIO5", bias = "pull-up" }``."""
    if isinstance(raw, str):
        return _line(raw, path), "as-is"
    t = _table(raw, path, _LINE_KEYS)
    if "line" not in t:
        raise WiringError(f"{path}.line: missing")
    return _line(t["line"], f"{path}.line"), _choice(t.get("bias", "as-is"), f"{path}.bias",
                                                     BIASES)


def _choice(raw: object, path: str, choices: tuple[str, ...]) -> str:
    if not isinstance(raw, str) or raw not in choices:
        raise WiringError(f"{path}: {raw!r} is not one of {', '.join(choices)}")
    return raw


def _number(raw: object, path: str, lo: float, hi: float, integer: bool = False) -> float:
    ok = isinstance(raw, int) if integer else isinstance(raw, int | float)
    if isinstance(raw, bool) or not ok:
        raise WiringError(f"{path}: must be {'an integer' if integer else 'a number'} "
                          f"in {lo:g}..{hi:g}")
    assert isinstance(raw, int | float)
    if not lo <= raw <= hi:
        raise WiringError(f"{path}: {raw} is out of range {lo:g}..{hi:g}")
    return float(raw)


def _flag(raw: object, path: str) -> bool:
    if not isinstance(raw, bool):
        raise WiringError(f"{path}: must be true or false")
    return raw


def parse_wiring(raw: object) -> GpioWiring:
    """The ``[gpiod]`` table as :class:`GpioWiring`; the first problem raises WiringError."""
    top = _table(raw, "gpiod", _TOP_KEYS)
    api = _choice(top.get("api", "auto"), "gpiod.api", ("auto", "v1", "v2"))
    consumer = top.get("consumer", "motorctl")
    if not isinstance(consumer, str) or not 0 < len(consumer) <= 31:
        raise WiringError("gpiod.consumer: must be a string of 1..31 characters")
    motors = top.get("motors", [])
    if not isinstance(motors, list):
        raise WiringError("gpiod.motors: must be an array of tables [[gpiod.motors]]")
    mw = []
    for i, m in enumerate(motors):
        p = f"gpiod.motors[{i}]"
        t = _table(m, p, _MOTOR_KEYS)
        for k in ("step", "dir"):
            if k not in t:
                raise WiringError(f"{p}.{k}: missing (the {k.upper()} line)")
        ends: dict[str, EndstopWiring | None] = {}
        for k in ("endstop_min", "endstop_max"):
            ends[k] = None
            if k in t:
                ref, bias = _line_bias(t[k], f"{p}.{k}")
                ends[k] = EndstopWiring(ref, bias)
        mw.append(MotorWiring(
            step=_line(t["step"], f"{p}.step"),
            dir=_line(t["dir"], f"{p}.dir"),
            enable=_line(t["enable"], f"{p}.enable") if "enable" in t else None,
            enable_active_low=_flag(t.get("enable_active_low", True), f"{p}.enable_active_low"),
            dir_hold_us=_number(t.get("dir_hold_us", 0.0), f"{p}.dir_hold_us", 0, 10_000),
            endstop_min=ends["endstop_min"],
            endstop_max=ends["endstop_max"],
        ))
    dc = None
    if "dc" in top:
        t = _table(top["dc"], "gpiod.dc", _DC_KEYS)
        for k in ("in1", "in2"):
            if k not in t:
                raise WiringError(f"gpiod.dc.{k}: missing (the bridge's {k.upper()} line)")
        pwm = None
        if "pwm" in t:
            pt = _table(t["pwm"], "gpiod.dc.pwm", _PWM_KEYS)
            for k in ("chip", "channel"):
                if k not in pt:
                    raise WiringError(f"gpiod.dc.pwm.{k}: missing")
            sysfs = pt.get("sysfs", "/sys/class/pwm")
            if not isinstance(sysfs, str):
                raise WiringError("gpiod.dc.pwm.sysfs: must be a path")
            pwm = PwmWiring(
                chip=int(_number(pt["chip"], "gpiod.dc.pwm.chip", 0, 255, True)),
                channel=int(_number(pt["channel"], "gpiod.dc.pwm.channel", 0, 255, True)),
                period_ns=int(_number(pt.get("period_ns", 50_000), "gpiod.dc.pwm.period_ns",
                                      1_000, 1_000_000_000, True)),
                duty=_number(pt.get("duty", 1.0), "gpiod.dc.pwm.duty", 0.0, 1.0),
                sysfs=sysfs,
            )
        dc = DcWiring(
            in1=_line(t["in1"], "gpiod.dc.in1"),
            in2=_line(t["in2"], "gpiod.dc.in2"),
            en=_line(t["en"], "gpiod.dc.en") if "en" in t else None,
            dead_time_ms=_number(t.get("dead_time_ms", 0.0), "gpiod.dc.dead_time_ms", 0, 10_000),
            reverse_via=_choice(t.get("reverse_via", "coast"), "gpiod.dc.reverse_via",
                                BRIDGE_STOPS),
            pwm=pwm,
        )
    pins_raw = top.get("pins", {})
    if not isinstance(pins_raw, dict):
        raise WiringError("gpiod.pins: must be a table of PIN_NR = line, e.g. 0 = \"GPIO5\"")
    pins = []
    for key, value in pins_raw.items():
        if not key.isdigit() or not 0 <= int(key) <= 255:
            raise WiringError(f"gpiod.pins.{key}: the key must be a PIN_NR 0..255 from [[pins]]")
        ref, bias = _line_bias(value, f"gpiod.pins.{key}")
        pins.append(PinWiring(int(key), ref, bias))
    wiring = GpioWiring(api=api, consumer=consumer, motors=tuple(mw), dc=dc,
                        pins=tuple(sorted(pins, key=lambda p: p.number)))
    dup = wiring.duplicates()
    if dup:
        raise WiringError(f"gpiod: {dup[0]}; each line can have one use")
    return wiring


def check_against(wiring: GpioWiring, motors: int, pins: set[int], dc: bool) -> str | None:
    """Does the wiring fit the machine (one entry per motor, a line per pin, the bridge)?"""
    if len(wiring.motors) != motors:
        return (f"gpiod.motors: {len(wiring.motors)} [[gpiod.motors]] entries for {motors} "
                "[[motors]]; wire each motor, in the same order")
    wired = {p.number for p in wiring.pins}
    if wired != pins:
        return (f"gpiod.pins: every [[pins]] number needs a line: missing "
                f"{sorted(pins - wired) or 'none'}, not in [[pins]] "
                f"{sorted(wired - pins) or 'none'}")
    if (wiring.dc is not None) != dc:
        return "gpiod.dc: [gpiod.dc] and [dc] go together: wire the bridge or remove [dc]"
    return None
