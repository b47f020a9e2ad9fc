"""Configuration: one TOML file checked against a declarative schema (Klipper style).

Every key has a type, a default and bounds; unknown keys are refused. Any problem raises
ConfigError naming the file, the key path, the problem and what is accepted.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import re
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from motorctl.hal.wiring import GpioWiring
    from motorctl.protocol.codec import CodecOptions

EMBEDDED_SOURCE: Final = "<embedded default>"
"""`Config.source` of the embedded default configuration."""

POSITION_MIN: Final = -(1 << 23)
POSITION_MAX: Final = (1 << 23) - 1


class ConfigError(Exception):
    """A configuration that cannot be used; the message says where, what and what is accepted."""


# --------------------------------------------------------------------------------------------
# The result: frozen dataclasses. Field names equal the TOML key names.


@dataclass(frozen=True)
class LinkConfig:
    """[link]: framing and checksum of the UART protocol."""

    frame_gap_ms: float
    checksum: str
    crc_covers_ack: bool
    strict_padding: bool
    held_frames: int

    def codec_options(self) -> CodecOptions:
        """The codec settings this table selects (crc None for checksum "none")."""
        from motorctl.protocol.codec import CodecOptions
        from motorctl.protocol.crc import SMBUS, Crc8, crc8_by_name

        crc: Crc8 | None
        if self.checksum == "none":
            crc = None
        elif self.checksum == "crc8":
            crc = SMBUS
        else:
            crc = crc8_by_name(self.checksum)
        return CodecOptions(
            crc=crc, crc_covers_ack=self.crc_covers_ack, strict_padding=self.strict_padding
        )


@dataclass(frozen=True)
class UnitsConfig:
    """[units]: protocol byte -> physical unit factors."""

    run_speed_factor: float
    move_speed_factor: float
    accel_factor: float


@dataclass(frozen=True)
class HalConfig:
    """[hal]: which hardware backend drives the outputs."""

    backend: str


@dataclass(frozen=True)
class StepThreadConfig:
    """[step_thread]: timing of the step-generating thread."""

    dir_setup_us: float
    step_pulse_us: float
    late_threshold_us: float
    spin_us: float
    priority: int
    lock_memory: bool
    switch_interval_us: float
    driver_poll_ms: float
    cpu: int


@dataclass(frozen=True)
class DcConfig:
    """[dc]: the DC motor (only present when configured)."""

    invert_hiz: bool
    max_time_ms: int


@dataclass(frozen=True)
class HomingConfig:
    """[motors.homing]: how InitMove finds the end stop."""

    source: str
    speed: float
    max_travel: int
    pull_off: int
    second_speed: float


@dataclass(frozen=True)
class EndstopConfig:
    """[motors.endstop]: the end-stop input."""

    active_low: bool
    debounce_ms: float


@dataclass(frozen=True)
class MockAxisConfig:
    """[motors.mock]: the simulated axis of the mock backend."""

    endstop_min: int
    endstop_max: int


@dataclass(frozen=True)
class MotorConfig:
    """One [[motors]] entry; its index in Config.motors is its protocol number."""

    name: str
    steps_per_rev: int
    invert_dir: bool
    max_speed: float
    max_accel: float
    default_speed: float
    default_accel: float
    default_decel: float
    queue_depth: int
    max_waypoints: int
    soft_limit_min: int | None
    soft_limit_max: int | None
    homing: HomingConfig
    endstop: EndstopConfig
    mock: MockAxisConfig

    @property
    def rotary(self) -> bool:
        """True for a rotary axis (steps_per_rev > 0)."""
        return self.steps_per_rev > 0


@dataclass(frozen=True)
class PinConfig:
    """One [[pins]] entry: a pin the host may address by PIN_NR."""

    number: int
    mode: str
    initial: bool
    safe: bool

    @property
    def is_output(self) -> bool:
        """True when the pin starts as an output."""
        return self.mode == "output"


@dataclass(frozen=True)
class MockConfig:
    """[mock]: wiring of the simulated world."""

    wires: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Config:
    """The whole validated configuration."""

    link: LinkConfig
    units: UnitsConfig
    hal: HalConfig
    step_thread: StepThreadConfig
    motors: tuple[MotorConfig, ...]
    pins: tuple[PinConfig, ...]
    dc: DcConfig | None
    mock: MockConfig
    source: str
    gpiod: GpioWiring | None = None


# --------------------------------------------------------------------------------------------
# The schema: key specs, cross-key rules and tables.

_REQUIRED: Final = object()
_DEFAULT_NOTE: Final = " (the default value; set the key explicitly)"
_DEFAULTS: Final = object()  # an absent table means: all keys at their defaults


@dataclass(frozen=True)
class _Key:
    """One key: kind ("int", "float", "bool", "str", "pairs"), default, bounds, meaning."""

    name: str
    kind: str
    default: Any
    doc: str
    lo: float | None = None
    hi: float | str | None = None  # a str names an earlier key in scope (this or a parent table)
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    choices_note: str = ""
    pattern: str | None = None
    pattern_text: str = ""
    check: Callable[[str], str | None] | None = None  # extra string check -> problem or None
    check_text: str = ""
    check_listing: Callable[[], str] | None = None  # accepted values, listed in errors
    optional: bool = False
    unique: bool = False
    indexed_default: bool = False  # default is a format string with {index}
    default_text: str | None = None


_Violation = tuple[str, Any, str]  # (key path relative to the table, value, problem)


@dataclass(frozen=True)
class _Rule:
    """A rule across keys of one table; `keys` are the keys whose docs list it."""

    keys: tuple[str, ...]
    text: str
    check: Callable[[Mapping[str, Any]], _Violation | None]


@dataclass(frozen=True)
class _Table:
    """A table or an array of tables. `absent` is the raw value used when it is missing,
    _DEFAULTS for {}, _REQUIRED for an error, or None for "no such thing" (field is None)."""

    name: str
    header: str
    build: Callable[..., Any]
    doc: str
    keys: tuple[_Key, ...] = ()
    tables: tuple[_Table, ...] = ()
    rules: tuple[_Rule, ...] = ()
    array: bool = False
    min_items: int = 0
    max_items: int = 0
    absent: Any = _DEFAULTS
    absent_text: str = "all defaults"


def _int(name: str, default: Any, lo: int, hi: int | str, doc: str, **kw: Any) -> _Key:
    return _Key(name, "int", default, doc, lo=lo, hi=hi, **kw)


def _float(
    name: str, default: float, lo: float, hi: float | str, doc: str, lo_open: bool = False
) -> _Key:
    return _Key(name, "float", default, doc, lo=lo, hi=hi, lo_open=lo_open)


def _bool(name: str, default: bool, doc: str) -> _Key:
    return _Key(name, "bool", default, doc)


def _choice(name: str, default: str, choices: tuple[str, ...], doc: str, note: str = "") -> _Key:
    return _Key(name, "str", default, doc, choices=choices, choices_note=note)


def _check_checksum(value: str) -> str | None:
    """Problem with a checksum name, or None when it is usable."""
    if value in ("crc8", "none"):
        return None
    from motorctl.protocol.crc import crc8_by_name

    try:
        crc8_by_name(value)
    except ValueError:
        return "unknown CRC-8 name"
    return None


def _checksum_names() -> str:
    from motorctl.protocol.crc import CATALOGUE

    return ", ".join(sorted(CATALOGUE))


def _soft_limits_paired(v: Mapping[str, Any]) -> _Violation | None:
    lo, hi = v["soft_limit_min"], v["soft_limit_max"]
    if lo is not None and hi is None:
        return ("soft_limit_min", lo, "soft_limit_max is not set")
    if hi is not None and lo is None:
        return ("soft_limit_max", hi, "soft_limit_min is not set")
    return None


def _soft_limits_ordered(v: Mapping[str, Any]) -> _Violation | None:
    lo, hi = v["soft_limit_min"], v["soft_limit_max"]
    if lo is not None and hi is not None and lo >= hi:
        return ("soft_limit_min", lo, f"not below soft_limit_max = {hi}")
    return None


def _soft_limits_linear(v: Mapping[str, Any]) -> _Violation | None:
    spr = v["steps_per_rev"]
    if spr > 0:
        for key in ("soft_limit_min", "soft_limit_max"):
            if v[key] is not None:
                return (key, v[key], f"soft limit on a rotary axis (steps_per_rev = {spr})")
    return None


def _endstops_ordered(v: Mapping[str, Any]) -> _Violation | None:
    lo, hi = v["endstop_min"], v["endstop_max"]
    if lo >= hi:
        return ("endstop_min", lo, f"not below endstop_max = {hi}")
    return None


def _wires_on_pins(v: Mapping[str, Any]) -> _Violation | None:
    numbers = {pin.number for pin in v["pins"]}
    for i, wire in enumerate(v["mock"].wires):
        for pin in wire:
            if pin not in numbers:
                listed = ", ".join(str(n) for n in sorted(numbers)) or "none"
                problem = f"pin {pin} is not in [[pins]] (configured pins: {listed})"
                return (f"mock.wires[{i}]", list(wire), problem)
    return None


def _wires_disjoint(v: Mapping[str, Any]) -> _Violation | None:
    seen: dict[int, int] = {}
    for i, wire in enumerate(v["mock"].wires):
        for pin in wire:
            if pin in seen:
                where = "this wire" if seen[pin] == i else f"mock.wires[{seen[pin]}]"
                return (f"mock.wires[{i}]", list(wire), f"pin {pin} is also in {where}")
            seen[pin] = i
    return None


def _build_mock(wires: Sequence[Sequence[int]]) -> MockConfig:
    return MockConfig(wires=tuple((a, b) for a, b in wires))


_LINK = _Table(
    "link",
    "[link]",
    LinkConfig,
    "Framing and checksum of the UART protocol.",
    keys=(
        _float(
            "frame_gap_ms",
            10.0,
            0,
            10000,
            "Longest silence between two bytes of one frame; a longer gap discards the "
            "partial frame (framing error). 0 turns the gap rule off.",
        ),
        _Key(
            "checksum",
            "str",
            "crc8",
            'Checksum byte B9 / R4. "none": ignored on input, sent as 0x00.',
            check=_check_checksum,
            check_listing=_checksum_names,
            check_text='"crc8" (= CRC-8/SMBUS), "none", or a CRC-8 catalogue name '
            '(e.g. "CRC-8/MAXIM-DOW"; case-insensitive, the "CRC-8/" prefix may be left out)',
        ),
        _bool("crc_covers_ack", False, "true: the response CRC covers R0..R3, not R1..R3."),
        _bool(
            "strict_padding",
            True,
            "true: a non-zero padding byte gets E1; false accepts any padding.",
        ),
        _int(
            "held_frames",
            16,
            1,
            1024,
            "Frames kept in arrival order while a WaitMoved response is held; "
            "beyond that each gets E0.",
        ),
    ),
)

_UNITS = _Table(
    "units",
    "[units]",
    UnitsConfig,
    "Factors from protocol bytes to step/s and step/s^2.",
    keys=(
        _float(
            "run_speed_factor",
            4096.0,
            0,
            1e6,
            "step/s per SPEED unit for InitMove and Move.",
            lo_open=True,
        ),
        _float(
            "move_speed_factor",
            4.0,
            0,
            1e6,
            "step/s per SPEED unit for MoveTo and MoveToWayPoint.",
            lo_open=True,
        ),
        _float("accel_factor", 16.0, 0, 1e7, "step/s^2 per ACC / DEC unit.", lo_open=True),
    ),
)

_HAL = _Table(
    "hal",
    "[hal]",
    HalConfig,
    "Hardware backend.",
    keys=(
        _choice(
            "backend",
            "mock",
            ("mock", "gpiod"),
            'Hardware backend; "mock" simulates motors, end stops and wired pins; "gpiod" '
            "drives real GPIO lines, wired in [gpiod] (docs/hardware.md).",
        ),
    ),
)

_STEP_THREAD = _Table(
    "step_thread",
    "[step_thread]",
    StepThreadConfig,
    "Timing of the thread that generates step pulses.",
    keys=(
        _float("dir_setup_us", 5.0, 0, 10000, "DIR is set this long before the next step edge."),
        _float("step_pulse_us", 2.0, 0.1, 10000, "Minimum step pulse width."),
        _float(
            "late_threshold_us",
            100.0,
            1,
            1e6,
            "A step edge later than this counts as late.",
        ),
        _float(
            "spin_us",
            200.0,
            0,
            100000,
            "Sleep until this long before a deadline, busy-wait the rest.",
        ),
        _int(
            "priority",
            50,
            0,
            99,
            "SCHED_FIFO priority of the step thread; 0 = do not ask for real-time.",
        ),
        _bool("lock_memory", True, "mlockall() when permitted."),
        _float(
            "switch_interval_us",
            100.0,
            10,
            100000,
            "sys.setswitchinterval() for the daemon process.",
        ),
        _float(
            "driver_poll_ms",
            10.0,
            0.1,
            10000,
            "How often driver status (faults, stall) is polled while a motor moves.",
        ),
        _int(
            "cpu",
            -1,
            -1,
            1023,
            "Pin the step thread to this CPU (the other threads avoid it); -1 = no pinning.",
        ),
    ),
)

_DC = _Table(
    "dc",
    "[dc]",
    DcConfig,
    "The DC motor. Absent: no DC motor (DcMove answers E2). Present, even empty: a DC motor.",
    keys=(
        _bool("invert_hiz", False, "true inverts the meaning of DcMove's GO_HiZ byte."),
        _int("max_time_ms", 65535, 1, 65535, "Cap for the TIME of one run."),
    ),
    absent=None,
    absent_text="no DC motor",
)

_HOMING = _Table(
    "homing",
    "[motors.homing]",
    HomingConfig,
    "How InitMove finds the end stop.",
    keys=(
        _choice(
            "source",
            "endstop",
            ("endstop", "stall"),
            "What stops homing: the end-stop input, or the driver's stall flag.",
        ),
        _float(
            "speed",
            2000.0,
            0,
            "max_speed",
            "step/s used when InitMove's SPEED = 0.",
            lo_open=True,
        ),
        _int(
            "max_travel",
            40000,
            1,
            16777215,
            "Steps; no trigger within this distance -> the motor faults.",
        ),
        _int(
            "pull_off",
            0,
            0,
            1000000,
            "0 = one-phase homing; > 0 = back off this many steps after the first trigger "
            "and re-approach at second_speed.",
        ),
        _float(
            "second_speed",
            250.0,
            0,
            "max_speed",
            "step/s of the slow re-approach.",
            lo_open=True,
        ),
    ),
)

_ENDSTOP = _Table(
    "endstop",
    "[motors.endstop]",
    EndstopConfig,
    "The end-stop input.",
    keys=(
        _bool("active_low", False, "true: the input is active when it reads low."),
        _float(
            "debounce_ms",
            0.0,
            0,
            1000,
            "The input must read active this long before it counts.",
        ),
    ),
)

_MOCK_AXIS = _Table(
    "mock",
    "[motors.mock]",
    MockAxisConfig,
    "The simulated axis (mock backend only).",
    keys=(
        _int(
            "endstop_min",
            -10000,
            POSITION_MIN,
            POSITION_MAX,
            "Position of the simulated end stop below, relative to the start position 0.",
        ),
        _int(
            "endstop_max",
            10000,
            POSITION_MIN,
            POSITION_MAX,
            "Position of the simulated end stop above, relative to the start position 0.",
        ),
    ),
    rules=(_Rule(("endstop_min", "endstop_max"), "endstop_min < endstop_max", _endstops_ordered),),
)

_MOTORS = _Table(
    "motors",
    "[[motors]]",
    MotorConfig,
    "Stepper motors, numbered 0..N-1 in file order.",
    keys=(
        _Key(
            "name",
            "str",
            "motor{index}",
            "Name used in logs and tools.",
            pattern=r"[A-Za-z0-9_.-]{1,64}",
            pattern_text="1..64 letters, digits, '_', '-' or '.'",
            unique=True,
            indexed_default=True,
            default_text='"motor0", "motor1", ... (by index)',
        ),
        _int(
            "steps_per_rev",
            0,
            0,
            8388607,
            "0 = linear axis; > 0 = rotary axis, position kept in [0, steps_per_rev).",
        ),
        _bool("invert_dir", False, "Swap the DIR wiring (not the protocol's direction)."),
        _float("max_speed", 25000.0, 0, 200000, "step/s; faster requests are clamped.", True),
        _float(
            "max_accel",
            200000.0,
            0,
            1e7,
            "step/s^2; larger ACC / DEC are clamped.",
            lo_open=True,
        ),
        _float(
            "default_speed",
            2000.0,
            0,
            "max_speed",
            "step/s used when SPEED = 0, and by GoHome.",
            lo_open=True,
        ),
        _float(
            "default_accel", 8000.0, 0, "max_accel", "step/s^2 used when ACC = 0.", lo_open=True
        ),
        _float(
            "default_decel", 8000.0, 0, "max_accel", "step/s^2 used when DEC = 0.", lo_open=True
        ),
        _int(
            "queue_depth",
            16,
            1,
            1024,
            "Motion commands that may wait behind the one executing; more -> E0.",
        ),
        _int("max_waypoints", 255, 1, 255, "Size of the waypoint table; more -> E5."),
        _int(
            "soft_limit_min",
            None,
            POSITION_MIN,
            POSITION_MAX,
            "Lowest allowed target; a MoveTo outside the limits -> E1, a Move stops at them.",
            optional=True,
            default_text="unset",
        ),
        _int(
            "soft_limit_max",
            None,
            POSITION_MIN,
            POSITION_MAX,
            "Highest allowed target.",
            optional=True,
            default_text="unset",
        ),
    ),
    tables=(_HOMING, _ENDSTOP, _MOCK_AXIS),
    rules=(
        _Rule(
            ("soft_limit_min", "soft_limit_max"),
            "set both soft_limit_min and soft_limit_max, or neither",
            _soft_limits_paired,
        ),
        _Rule(
            ("soft_limit_min", "soft_limit_max"),
            "soft_limit_min < soft_limit_max",
            _soft_limits_ordered,
        ),
        _Rule(
            ("soft_limit_min", "soft_limit_max"),
            "only on a linear axis (steps_per_rev = 0)",
            _soft_limits_linear,
        ),
    ),
    array=True,
    min_items=1,
    max_items=64,
    absent=_REQUIRED,
    absent_text="required",
)

_PINS = _Table(
    "pins",
    "[[pins]]",
    PinConfig,
    "IO pins the host addresses by PIN_NR; no other pin is reachable.",
    keys=(
        _int("number", _REQUIRED, 0, 255, "The host's PIN_NR.", unique=True),
        _choice(
            "mode", "output", ("output", "input"), "Direction at start (ConfigPin changes it)."
        ),
        _bool("initial", False, "Output level at start (true = high)."),
        _bool("safe", False, "Output level set at shutdown (true = high)."),
    ),
    array=True,
    min_items=0,
    max_items=256,
    absent=[],
    absent_text="no pins",
)

_MOCK = _Table(
    "mock",
    "[mock]",
    _build_mock,
    "The simulated world of the mock backend. Absent: no wires.",
    keys=(
        _Key(
            "wires",
            "pairs",
            [[0, 4], [1, 5], [2, 6], [3, 7]],
            "Pins joined by a wire: an input reads the output it is wired to. This default "
            "applies only when a [mock] table is written; without [mock] there are no wires.",
        ),
    ),
    absent={"wires": []},
    absent_text="no wires",
)

_TOP = _Table(
    "",
    "the top level",
    Config,
    "The whole file.",
    tables=(_LINK, _UNITS, _HAL, _STEP_THREAD, _DC, _MOTORS, _PINS, _MOCK),
    rules=(
        _Rule(("mock.wires",), "every wired pin is listed in [[pins]]", _wires_on_pins),
        _Rule(("mock.wires",), "each pin in at most one wire", _wires_disjoint),
    ),
)


# --------------------------------------------------------------------------------------------
# Formatting


def _num(value: float) -> str:
    """A bound as people write it: 200000, not 200000.0."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def _toml_value(value: Any, limit: int = 80) -> str:
    """A value written as in TOML, shortened to `limit` characters."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
    elif isinstance(value, float):
        text = "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        if math.isfinite(value):
            text = repr(value)
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(_toml_value(v, limit) for v in value) + "]"
    elif isinstance(value, dict):
        inner = ", ".join(f"{k} = {_toml_value(v, limit)}" for k, v in value.items())
        text = "{ " + inner + " }" if inner else "{}"
    elif isinstance(value, datetime.date | datetime.time):
        text = value.isoformat()
    else:
        text = str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _toml_type(value: Any) -> str:
    """The TOML type name of a parsed value."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, datetime.datetime):
        return "date-time"
    if isinstance(value, datetime.date):
        return "date"
    if isinstance(value, datetime.time):
        return "time"
    return type(value).__name__


def _type_text(key: _Key) -> str:
    base = {
        "int": "integer",
        "float": "number",
        "bool": "boolean",
        "str": "string",
        "pairs": "array of [pin, pin]",
    }[key.kind]
    return base + " (optional)" if key.optional else base


def _accepted(key: _Key, scope: Mapping[str, Any] | None = None) -> str:
    """What a key accepts; with `scope`, bounds that name other keys show their values."""
    hi_text = ""
    if isinstance(key.hi, str):
        hi_text = key.hi
        if scope is not None and key.hi in scope:
            hi_text += f" ({key.hi} = {_num(scope[key.hi])})"
    elif key.hi is not None:
        hi_text = _num(key.hi)
    if key.kind in ("int", "float"):
        noun = "an integer" if key.kind == "int" else "a number"
        assert key.lo is not None
        if key.lo_open or isinstance(key.hi, str):
            op = ">" if key.lo_open else ">="
            text = f"{noun} {op} {_num(key.lo)} and <= {hi_text}"
        else:
            text = f"{noun} in {_num(key.lo)}..{hi_text}"
        if key.optional:
            text += ", or leave it unset"
        if key.default is _REQUIRED:
            text += " (required)"
    elif key.kind == "bool":
        text = "true or false"
    elif key.kind == "pairs":
        text = "an array of [pin, pin] pairs of pin numbers 0..255"
    elif key.choices:
        text = "one of " + ", ".join(json.dumps(c) for c in key.choices)
        if key.choices_note:
            text += f" ({key.choices_note})"
    elif key.pattern is not None:
        text = f"a string of {key.pattern_text}"
    else:
        text = key.check_text
    if key.unique:
        text += ", unique"
    return text


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


# --------------------------------------------------------------------------------------------
# Validation


class _Parser:
    """Walks the parsed TOML document along the schema; the first problem raises."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.defaulted: set[str] = set()  # key paths that took their default value

    def error(self, path: str, value: Any, problem: str, accepted: str) -> ConfigError:
        shown = f"{path} = {_toml_value(value)}" if value is not _REQUIRED else path
        return ConfigError(f"{self.source}: {shown}: {problem}; accepted: {accepted}")

    def table(
        self, spec: _Table, raw: Any, path: str, scope: Mapping[str, Any], index: int = 0
    ) -> dict[str, Any]:
        """Validated values of one table (sub-tables built), keyed by field name."""
        if not isinstance(raw, dict):
            raise self.error(path, raw, f"wrong type ({_toml_type(raw)})", f"a table {spec.header}")
        allowed = sorted([k.name for k in spec.keys] + [t.name for t in spec.tables])
        for name in raw:
            if name not in allowed:
                where = f"keys in {spec.header}" if path else "top-level keys"
                raise ConfigError(
                    f"{self.source}: unknown key '{_join(path, name)}'; "
                    f"accepted {where}: {', '.join(allowed)}"
                )
        values: dict[str, Any] = {}
        inner = dict(scope)
        for key in spec.keys:
            values[key.name] = self.key(key, raw, _join(path, key.name), inner, index)
            inner[key.name] = values[key.name]
        for sub in spec.tables:
            values[sub.name] = self.child(sub, raw.get(sub.name, _REQUIRED), path, inner)
        for rule in spec.rules:
            violation = rule.check(values)
            if violation is not None:
                where, value, problem = violation
                where = _join(path, where)
                if re.sub(r"\[\d+\]$", "", where) in self.defaulted:
                    problem += _DEFAULT_NOTE
                raise self.error(where, value, problem, rule.text)
        return values

    def child(self, spec: _Table, raw: Any, parent: str, scope: Mapping[str, Any]) -> Any:
        """A sub-table or array of tables of the parent at `parent`, built."""
        path = _join(parent, spec.name)
        if raw is _REQUIRED:
            if spec.absent is _REQUIRED:
                raise self.error(
                    path,
                    _REQUIRED,
                    "missing",
                    f"{spec.min_items}..{spec.max_items} {spec.header} tables "
                    f"(a config needs at least one)",
                )
            if spec.absent is None:
                return None
            raw = {} if spec.absent is _DEFAULTS else spec.absent
        if not spec.array:
            return spec.build(**self.table(spec, raw, path, scope))
        count = f"{spec.min_items}..{spec.max_items} {spec.header} tables"
        if not isinstance(raw, list):
            raise self.error(
                path, raw, f"wrong type ({_toml_type(raw)})", f"an array of tables: {count}"
            )
        if not spec.min_items <= len(raw) <= spec.max_items:
            raise self.error(path, _REQUIRED, f"{len(raw)} entries", count)
        items = []
        seen: dict[str, dict[Any, int]] = {k.name: {} for k in spec.keys if k.unique}
        for i, item_raw in enumerate(raw):
            item_path = f"{path}[{i}]"
            item = spec.build(**self.table(spec, item_raw, item_path, scope, i))
            for key in spec.keys:
                if not key.unique:
                    continue
                value = getattr(item, key.name)
                if value in seen[key.name]:
                    first = seen[key.name][value]
                    raise self.error(
                        f"{item_path}.{key.name}",
                        value,
                        f"duplicate ({path}[{first}].{key.name} is also {_toml_value(value)})",
                        f"a value used by no other {spec.header} entry",
                    )
                seen[key.name][value] = i
            items.append(item)
        return tuple(items)

    def key(
        self, key: _Key, raw: Mapping[str, Any], path: str, scope: Mapping[str, Any], index: int
    ) -> Any:
        """The validated value of one key (its default when absent)."""
        if key.name in raw:
            return self.convert(key, raw[key.name], path, scope)
        if key.default is _REQUIRED:
            raise self.error(path, _REQUIRED, "missing", _accepted(key))
        if key.optional:
            return None
        if key.indexed_default:
            return str(key.default).format(index=index)
        self.defaulted.add(path)
        return self.convert(key, key.default, path, scope, _DEFAULT_NOTE)

    def convert(
        self, key: _Key, value: Any, path: str, scope: Mapping[str, Any], note: str = ""
    ) -> Any:
        """Type- and range-check one value; floats accept integers."""
        accepted = _accepted(key, scope)
        type_problem = f"wrong type ({_toml_type(value)})"
        if key.kind in ("int", "float"):
            number_types = int if key.kind == "int" else int | float
            if isinstance(value, bool) or not isinstance(value, number_types):
                raise self.error(path, value, type_problem, accepted)
            lo = key.lo
            hi = scope[key.hi] if isinstance(key.hi, str) else key.hi
            assert lo is not None and hi is not None
            in_range = (value > lo if key.lo_open else value >= lo) and value <= hi
            if not in_range:
                raise self.error(path, value, "out of range" + note, accepted)
            return float(value) if key.kind == "float" else value
        if key.kind == "bool":
            if not isinstance(value, bool):
                raise self.error(path, value, type_problem, accepted)
            return value
        if key.kind == "str":
            if not isinstance(value, str):
                raise self.error(path, value, type_problem, accepted)
            if key.choices and value not in key.choices:
                raise self.error(path, value, "unknown value", accepted)
            if key.pattern is not None and re.fullmatch(key.pattern, value) is None:
                raise self.error(path, value, "not a valid name", accepted)
            if key.check is not None:
                problem = key.check(value)
                if problem is not None:
                    if key.check_listing is not None:
                        accepted = f"{accepted}: {key.check_listing()}"
                    raise self.error(path, value, problem, accepted)
            return value
        return self.pairs(value, path, accepted)

    def pairs(self, value: Any, path: str, accepted: str) -> list[list[int]]:
        """An array of [pin, pin] pairs."""
        if not isinstance(value, list):
            raise self.error(path, value, f"wrong type ({_toml_type(value)})", accepted)
        for i, pair in enumerate(value):
            ok = (
                isinstance(pair, list)
                and len(pair) == 2
                and all(isinstance(p, int) and not isinstance(p, bool) for p in pair)
            )
            if not ok:
                raise self.error(f"{path}[{i}]", pair, "not a [pin, pin] pair", accepted)
            if not all(0 <= p <= 255 for p in pair):
                raise self.error(f"{path}[{i}]", pair, "pin number out of range", accepted)
        return [list(pair) for pair in value]


# --------------------------------------------------------------------------------------------
# Public functions


_TOML_POSITION = re.compile(r"\(at line (\d+), column (\d+)\)$")


def parse_config(text: str, source: str) -> Config:
    """Validate TOML `text`; `source` (a path, usually) starts every error message."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        match = _TOML_POSITION.search(message)
        if match is not None:
            line = int(match.group(1))
        else:  # "(at end of document)"
            line = max(1, text.count("\n") + (0 if text.endswith("\n") else 1))
        raise ConfigError(f"{source}: line {line}: TOML syntax error: {message}") from None
    gpiod_raw = document.pop("gpiod", None)
    parser = _Parser(source)
    values = parser.table(_TOP, document, "", {})
    config = Config(**values, source=source)
    return _with_gpiod(config, gpiod_raw)


def _with_gpiod(config: Config, raw: Any) -> Config:
    """The [gpiod] section: owned and parsed by the gpiod backend (motorctl.hal.wiring)."""
    from motorctl.hal.wiring import WiringError, check_against, parse_wiring

    source = config.source
    if raw is None:
        if config.hal.backend == "gpiod":
            raise ConfigError(f"{source}: [hal] backend = \"gpiod\" needs a [gpiod] section that "
                              "wires the motors, end stops, DC bridge and pins "
                              "(docs/hardware.md)")
        return config
    try:
        wiring = parse_wiring(raw)
    except WiringError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    problem = check_against(wiring, len(config.motors), {p.number for p in config.pins},
                            config.dc is not None)
    if problem is not None:
        raise ConfigError(f"{source}: {problem}")
    return dataclasses.replace(config, gpiod=wiring)


def default_config_text() -> str:
    """The embedded default configuration (daemon/default.toml)."""
    return resources.files("daemon").joinpath("default.toml").read_text(encoding="utf-8")


def load_config(path: str | os.PathLike[str] | None) -> Config:
    """Read and validate the config file at `path`; None loads the embedded default."""
    if path is None:
        return parse_config(default_config_text(), EMBEDDED_SOURCE)
    source = os.fspath(path)
    try:
        with open(source, "rb") as file:
            data = file.read()
    except FileNotFoundError:
        raise ConfigError(
            f"{source}: config file not found; fix: create it (`motorctld "
            "--print-default-config` prints a commented example; docs/config.md describes "
            "every key) or give the path of an existing file"
        ) from None
    except OSError as exc:
        raise ConfigError(
            f"{source}: cannot read config file: {exc.strerror}; "
            "fix: give the path of a readable TOML file"
        ) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{source}: line {line}: not valid UTF-8; accepted: a UTF-8 encoded TOML file"
        ) from None
    return parse_config(text, source)


def _describe(
    spec: _Table, prefix: str, notes: dict[str, list[str]], rows: list[tuple[str, str, str, str]]
) -> None:
    for rule in spec.rules:
        for name in rule.keys:
            notes.setdefault(_join(prefix, name), []).append(rule.text)
    for key in spec.keys:
        path = _join(prefix, key.name)
        if key.default_text is not None:
            default = key.default_text
        elif key.default is _REQUIRED:
            default = "required"
        elif key.kind == "float":
            default = repr(float(key.default))
        else:
            default = _toml_value(key.default)
        accepted = "; ".join([_accepted(key), *notes.get(path, [])])
        rows.append((path, _type_text(key), default, f"{accepted}. {key.doc}"))
    for sub in spec.tables:
        path = _join(prefix, sub.name)
        if sub.array:
            kind = "array of tables"
            accepted = f"{sub.min_items}..{sub.max_items} {sub.header} tables"
        else:
            kind = "table"
            accepted = f"a table {sub.header}"
        rows.append((path, kind, sub.absent_text, f"{accepted}. {sub.doc}"))
        _describe(sub, path + "[]" if sub.array else path, notes, rows)


def describe_keys() -> list[tuple[str, str, str, str]]:
    """(key path, type, default, accepted values and meaning) of every key and table.

    Arrays of tables are written `motors[]`; generated from the schema used to validate.
    """
    rows: list[tuple[str, str, str, str]] = []
    _describe(_TOP, "", {}, rows)
    rows.append(("gpiod", "table", "absent", "a table [gpiod], required by backend \"gpiod\". "
                 "The wiring of the gpiod backend (lines of the motors, end stops, DC bridge and "
                 "pins); its keys are in docs/hardware.md."))
    return rows
