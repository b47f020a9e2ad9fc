"""Tests for motorctl.daemon.config and motorctl.schema: the embedded default, defaults, every
kind of error, backend sections, docs."""

from __future__ import annotations

import dataclasses
import enum
import tomllib
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon.config import (
    Config,
    ConfigError,
    DcConfig,
    EndstopConfig,
    HalConfig,
    HomingConfig,
    LinkConfig,
    MotorConfig,
    PinConfig,
    StateConfig,
    StepThreadConfig,
    TraceConfig,
    UnitsConfig,
    default_config_text,
    describe_keys,
    load_config,
    parse_config,
    schema,
)
from motorctl.daemon.config.docs import DOCS, render
from motorctl.hal.backends.gpiod.config import (
    GpiodAxisConfig,
    GpiodConfig,
    GpiodDcConfig,
    GpiodPinConfig,
    GpiodPwmConfig,
)
from motorctl.hal.backends.mock.config import MockAxisConfig, MockConfig
from motorctl.hal.layers.dspin.config import DspinAxisConfig, DspinConfig
from motorctl.hal.layers.tmc.config import SpidevConfig, TmcAxisConfig
from motorctl.hal.poller import DriversConfig
from motorctl.motion.types import HomingSource
from motorctl.protocol.codec import CodecOptions
from motorctl.protocol.crc import SMBUS, crc8_by_name
from motorctl.schema import Table

SOURCE = "/etc/motorctl.toml"
MOTOR = "[[motors]]\n"


def error_of(text: str) -> str:
    """The ConfigError message that parsing `text` produces."""
    with pytest.raises(ConfigError) as info:
        parse_config(text, SOURCE)
    return str(info.value)


def lookup(config: Any, path: str) -> Any:
    """Follow a describe_keys path ('motors[].homing.speed') into motor 0 / pin 0; a backend's
    section ('motors[].mock') is read from the parent's sections, as the code reads it."""
    value, spec = config, schema()
    for part in path.split("."):
        name = part.removesuffix("[]")
        child = next((c for c in spec.children if c.name == name), None)
        if child is None:
            value = getattr(value, name)
            continue
        value = value.section(child.table.cls) if child.extension else getattr(value, name)
        if part.endswith("[]"):
            value = value[0]
        spec = child.table
    return value


# --- the embedded default ---------------------------------------------------------------------


def test_embedded_default_world() -> None:
    config = load_config(None)
    assert config.source == "<embedded default>"
    assert [m.name for m in config.motors] == ["x", "y", "z"]
    for motor in config.motors:
        assert not motor.rotary
        assert motor.steps_per_rev == 0
        mock = motor.section(MockAxisConfig)
        assert (mock.endstop_min, mock.endstop_max) == (-10000, 10000)
        assert motor.max_speed == 25000.0
        assert motor.queue_depth == 16
        assert motor.max_waypoints == 255
        assert motor.soft_limit_min is None and motor.soft_limit_max is None
    assert config.dc is not None
    assert [p.number for p in config.pins] == list(range(8))
    for pin in config.pins[:4]:
        assert pin.is_output and pin.mode == "output"
        assert (pin.initial, pin.safe) == (False, False)
    for pin in config.pins[4:]:
        assert not pin.is_output and pin.mode == "input"
    assert config.section(MockConfig).wires == ((0, 4), (1, 5), (2, 6), (3, 7))
    assert config.hal.backend == "mock"
    assert config.link.codec_options() == CodecOptions()


def test_embedded_default_matches_schema_defaults() -> None:
    """The embedded world sets names, [dc], pins and [mock] only: all else is at the defaults."""
    embedded = load_config(None)
    minimal = parse_config(MOTOR + "[dc]\n", "minimal")
    for motor in embedded.motors:
        assert dataclasses.replace(motor, name="motor0") == minimal.motors[0]
    for table in ("link", "units", "hal", "step_thread", "dc"):
        assert getattr(embedded, table) == getattr(minimal, table)


def test_default_config_text_loads_back_to_the_embedded_default() -> None:
    """--print-default-config's text is the embedded default, every key written out."""
    text = default_config_text()
    assert parse_config(text, "copy") == dataclasses.replace(load_config(None), source="copy")
    lines = text.splitlines()
    assert lines[0].startswith("# motorctl: the embedded default configuration")
    left_out = {ln[3:].split("]")[0] for ln in lines if ln.startswith("# [") and ": left out" in ln}

    def inside_left_out(table: str) -> bool:
        return any(table == t or table.startswith(t + ".") for t in left_out)

    for path, type_, _, _ in describe_keys():
        table = path.replace("[]", "").rpartition(".")[0]
        if type_ in ("table", "array of tables"):
            here = path.replace("[]", "")
            assert f"[{here}]" in text or f"[[{path}]]" in text or inside_left_out(here), path
            continue
        if inside_left_out(table):  # an optional table the embedded default leaves out
            continue
        name = path.split(".")[-1]
        written = [ln for ln in lines if ln.startswith((f"{name} = ", f"# {name} = (unset)"))]
        assert written, f"{path} is not written out"
    # every value is commented with what it accepts
    assert "# Steps; no trigger (or release) within them -> fault. Accepted: an integer" in text


# --- defaults and values ----------------------------------------------------------------------


def test_minimal_file_fills_defaults(tmp_path: Path) -> None:
    path = tmp_path / "motorctl.toml"
    path.write_text(MOTOR, encoding="utf-8")
    config = load_config(path)
    assert config.source == str(path)
    assert len(config.motors) == 1
    motor = config.motors[0]
    assert motor.name == "motor0"
    assert (motor.max_speed, motor.default_speed, motor.max_accel) == (25000.0, 2000.0, 200000.0)
    assert (motor.default_accel, motor.default_decel) == (8000.0, 8000.0)
    assert motor.homing == HomingConfig(HomingSource.ENDSTOP, 2000.0, 40000, 0, 250.0)
    assert motor.endstop == EndstopConfig(False, 0.0)
    assert motor.homing.source is HomingSource.ENDSTOP
    assert motor.section(MockAxisConfig) == MockAxisConfig(-10000, 10000, True)
    assert config.pins == ()
    assert config.dc is None
    assert config.section(MockConfig) == MockConfig(lose_steps=False, wires=())
    assert config.link == LinkConfig(10.0, "crc8", False, True, 16, 0.0, "decelerate")
    assert config.units == UnitsConfig(4096.0, 4.0, 16.0)
    assert config.hal == HalConfig("mock")
    assert config.step_thread == StepThreadConfig(
        5.0, 2.0, 100.0, 200.0, 50, True, 100.0, -1, "process", 50.0, 3.0, 50.0, "auto"
    )
    assert load_config(str(path)) == config


def test_defaults_agree_with_describe_keys() -> None:
    """Every key's documented default is the value a file without it gets."""
    optional = "[motors.tmc]\n"  # optional tables written empty: their keys at the defaults
    config = parse_config(MOTOR + optional + "[dc]\n[[pins]]\nnumber = 0\n", SOURCE)
    # a motor has one driver chip: the dSPIN layer's tables in a config of their own
    dspin = parse_config(MOTOR + "[motors.dspin]\n[dspin]\n", SOURCE)
    checked = 0
    for path, type_, default, _ in describe_keys():
        if type_ in ("table", "array of tables") or default in ("required", "unset"):
            continue
        if path in ("motors[].name", "mock.wires", "motors[].microsteps"):
            continue  # (microsteps: test_microsteps_come_from_the_motor_or_its_tmc_table)
        if path.split(".")[0] == "gpiod" or ".gpiod" in path:
            # not in this config; tests/hal/backends/gpiod/test_config.py checks those defaults
            continue
        expected = tomllib.loads(f"v = {default}")["v"]
        actual = lookup(dspin if path.split(".")[-2] == "dspin" else config, path)
        assert actual == expected, path
        if isinstance(actual, enum.Enum):  # a choice the code reads as an enum member
            actual = actual.value
        assert type(actual) is (float if type_ == "number" else type(expected)), path
        checked += 1
    assert checked >= 40


def test_default_wires_apply_when_mock_table_is_written() -> None:
    pins = "".join(f"[[pins]]\nnumber = {n}\n" for n in range(8))
    config = parse_config(MOTOR + pins + "[mock]\n", SOURCE)
    assert config.section(MockConfig).wires == ((0, 4), (1, 5), (2, 6), (3, 7))


def test_describe_keys_covers_every_dataclass_field() -> None:
    """Each field of each table's dataclass is a documented key (except the `sections` that
    hold backends' tables and Config.source), and nothing else is."""
    paths = {row[0] for row in describe_keys()}
    tables: list[tuple[str, type[Any]]] = [
        ("link", LinkConfig),
        ("units", UnitsConfig),
        ("hal", HalConfig),
        ("step_thread", StepThreadConfig),
        ("state", StateConfig),
        ("trace", TraceConfig),
        ("dc", DcConfig),
        ("motors[]", MotorConfig),
        ("motors[].homing", HomingConfig),
        ("motors[].endstop", EndstopConfig),
        ("motors[].mock", MockAxisConfig),
        ("pins[]", PinConfig),
        ("mock", MockConfig),
        ("gpiod", GpiodConfig),
        ("gpiod.dc", GpiodDcConfig),
        ("gpiod.dc.pwm", GpiodPwmConfig),
        ("motors[].gpiod", GpiodAxisConfig),
        ("pins[].gpiod", GpiodPinConfig),
        ("motors[].tmc", TmcAxisConfig),
        ("spidev", SpidevConfig),
        ("motors[].dspin", DspinAxisConfig),
        ("dspin", DspinConfig),
        ("drivers", DriversConfig),
    ]
    expected = {
        f"{prefix}.{f.name}"
        for prefix, cls in tables
        for f in dataclasses.fields(cls)
        if f.name != "sections"
    }
    given = ("sections", "source", "notices")  # not keys: filled by the loader
    expected |= {f.name for f in dataclasses.fields(Config) if f.name not in given}
    expected |= {"mock", "motors[].mock"}  # the mock backend's tables, in `sections`
    expected |= {"gpiod", "motors[].gpiod", "pins[].gpiod"}  # the gpiod backend's
    expected |= {"spidev", "motors[].tmc"}  # the TMC layer's tables
    expected |= {"dspin", "motors[].dspin"}  # the dSPIN layer's
    expected |= {"drivers"}  # the HAL's own (its driver poller)
    assert expected == paths


def test_values_are_converted_and_frozen() -> None:
    config = parse_config(
        MOTOR
        + "name = 'a'\nsteps_per_rev = 200\nmax_speed = 3000\ndefault_speed = 2999\n"
        + "[[motors]]\nname = 'b'\nsoft_limit_min = -5\nsoft_limit_max = 5\n"
        + "[[pins]]\nnumber = 9\nmode = 'input'\ninitial = true\nsafe = true\n",
        SOURCE,
    )
    a, b = config.motors
    assert a.rotary and not b.rotary
    assert isinstance(a.max_speed, float) and a.max_speed == 3000.0
    assert (b.soft_limit_min, b.soft_limit_max) == (-5, 5)
    assert config.pins == (PinConfig(9, "input", True, True, sections=config.pins[0].sections),)
    assert not config.pins[0].is_output
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.max_speed = 5.0  # type: ignore[misc]


def test_bounds_are_inclusive_where_documented() -> None:
    config = parse_config(
        "[link]\nframe_gap_ms = 0\nheld_frames = 1024\n"
        "[step_thread]\npriority = 0\nstep_pulse_us = 0.1\n"
        + MOTOR
        + "max_speed = 200000\ndefault_speed = 200000\nmax_waypoints = 1\n"
        "[motors.mock]\nendstop_min = -8388608\nendstop_max = 8388607\n",
        SOURCE,
    )
    assert config.link.frame_gap_ms == 0.0
    assert config.motors[0].default_speed == config.motors[0].max_speed


# --- codec options ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("checksum", "expected"),
    [
        ("crc8", SMBUS),
        ("none", None),
        ("CRC-8/MAXIM-DOW", crc8_by_name("CRC-8/MAXIM-DOW")),
        ("maxim-dow", crc8_by_name("CRC-8/MAXIM-DOW")),
        ("CRC-8/ROHC", crc8_by_name("CRC-8/ROHC")),
    ],
)
def test_codec_options(checksum: str, expected: Any) -> None:
    text = f'[link]\nchecksum = "{checksum}"\ncrc_covers_ack = true\nstrict_padding = false\n'
    options = parse_config(text + MOTOR, SOURCE).link.codec_options()
    assert options == CodecOptions(crc=expected, crc_covers_ack=True, strict_padding=False)
    assert parse_config(text + MOTOR, SOURCE).link.checksum == checksum


def test_named_variant_differs_from_smbus() -> None:
    crc = parse_config('[link]\nchecksum = "CRC-8/MAXIM-DOW"\n' + MOTOR, SOURCE).link
    options = crc.codec_options()
    assert options.crc is not None and options.crc != SMBUS
    assert options.crc.compute(b"123456789") == 0xA1


# --- errors -----------------------------------------------------------------------------------

PINS_0_TO_3 = "".join(f"[[pins]]\nnumber = {n}\n" for n in range(4))

ERRORS: list[tuple[str, str, list[str]]] = [
    # (id, file text, fragments the message must contain besides SOURCE)
    # unknown keys, at every level
    ("unknown-top", "foo = 1\n" + MOTOR, ["unknown key 'foo'", "link, mock, motors, pins"]),
    (
        "unknown-link",
        "[link]\nframe_gap = 1\n" + MOTOR,
        [
            "unknown key 'link.frame_gap'; accepted keys in [link]: checksum, crc_covers_ack, "
            "frame_gap_ms, held_frames, strict_padding"
        ],
    ),
    ("unknown-units", "[units]\nspeed = 1\n" + MOTOR, ["'units.speed'", "accel_factor"]),
    ("unknown-hal", "[hal]\nbackends = 1\n" + MOTOR, ["'hal.backends'", "in [hal]: backend"]),
    ("unknown-step", "[step_thread]\nprio = 1\n" + MOTOR, ["'step_thread.prio'", "priority"]),
    ("unknown-dc", "[dc]\nmax_time = 1\n" + MOTOR, ["'dc.max_time'", "invert_hiz, max_time_ms"]),
    ("unknown-motor", MOTOR + "speed = 1\n", ["'motors[0].speed'", "in [[motors]]", "max_speed"]),
    (
        "unknown-homing",
        MOTOR + "[motors.homing]\nspd = 1\n",
        ["'motors[0].homing.spd'", "in [motors.homing]", "second_speed, source, speed"],
    ),
    (
        "unknown-endstop",
        MOTOR + MOTOR + "[motors.endstop]\nlow = true\n",
        ["'motors[1].endstop.low'", "in [motors.endstop]: active_low, debounce_ms"],
    ),
    (
        "unknown-motor-mock",
        MOTOR + "[motors.mock]\nmin = 1\n",
        ["'motors[0].mock.min'", "in [motors.mock]: endstop_max, endstop_min"],
    ),
    (
        "unknown-pin",
        MOTOR + "[[pins]]\nnumber = 1\nlevel = 1\n",
        ["'pins[0].level'", "in [[pins]]: gpiod, initial, mode, number, safe"],
    ),
    (
        "unknown-mock",
        MOTOR + "[mock]\nwire = []\n",
        ["'mock.wire'", "in [mock]: lose_steps, wires"],
    ),
    # wrong types
    (
        "str-for-number",
        MOTOR + 'max_speed = "fast"\n',
        ['motors[0].max_speed = "fast"', "wrong type (string)", "a number > 0 and <= 200000"],
    ),
    (
        "float-for-int",
        MOTOR + "queue_depth = 16.0\n",
        ["motors[0].queue_depth = 16.0", "wrong type (float)", "an integer in 1..1024"],
    ),
    (
        "bool-for-int",
        "[link]\nheld_frames = true\n" + MOTOR,
        ["link.held_frames = true", "wrong type (boolean)", "an integer in 1..1024"],
    ),
    (
        "bool-for-float",
        "[link]\nframe_gap_ms = false\n" + MOTOR,
        ["link.frame_gap_ms = false", "wrong type (boolean)", "a number in 0..10000"],
    ),
    (
        "int-for-bool",
        "[link]\nstrict_padding = 1\n" + MOTOR,
        ["link.strict_padding = 1", "wrong type (integer)", "true or false"],
    ),
    (
        "int-for-str",
        MOTOR + "[motors.homing]\nsource = 1\n",
        ["motors[0].homing.source = 1", "wrong type (integer)", '"endstop", "stall"'],
    ),
    ("value-for-table", "link = 5\n" + MOTOR, ["link = 5", "wrong type", "a table [link]"]),
    (
        "value-for-subtable",
        MOTOR + "homing = 5\n",
        ["motors[0].homing = 5", "a table [motors.homing]"],
    ),
    (
        "table-for-array",
        '[motors]\nname = "a"\n',
        ["motors = ", "wrong type (table)", "1..64 [[motors]] tables"],
    ),
    ("wires-not-array", MOTOR + "[mock]\nwires = 5\n", ["mock.wires = 5", "[pin, pin] pairs"]),
    (
        "wire-not-pair",
        MOTOR + PINS_0_TO_3 + "[mock]\nwires = [[0, 1, 2]]\n",
        ["mock.wires[0] = [0, 1, 2]", "not a [pin, pin] pair", "[pin, pin] pairs"],
    ),
    (
        "wire-pin-range",
        MOTOR + PINS_0_TO_3 + "[mock]\nwires = [[0, 256]]\n",
        ["mock.wires[0] = [0, 256]", "out of range", "pin numbers 0..255"],
    ),
    # out of range
    (
        "out-of-range-open",
        MOTOR + MOTOR + "max_speed = 0\n",
        ["motors[1].max_speed = 0: out of range; accepted: a number > 0 and <= 200000"],
    ),
    (
        "out-of-range-high",
        MOTOR + "max_accel = 1e8\n",
        ["motors[0].max_accel = 100000000.0", "out of range", "<= 10000000"],
    ),
    (
        "out-of-range-int",
        "[step_thread]\npriority = 100\n" + MOTOR,
        ["step_thread.priority = 100", "out of range", "an integer in 0..99"],
    ),
    (
        "out-of-range-low",
        "[step_thread]\nstep_pulse_us = 0.05\n" + MOTOR,
        ["step_thread.step_pulse_us = 0.05", "out of range", "a number in 0.1..10000"],
    ),
    ("nan", "[units]\naccel_factor = nan\n" + MOTOR, ["units.accel_factor = nan", "out of range"]),
    ("inf", "[units]\naccel_factor = inf\n" + MOTOR, ["units.accel_factor = inf", "out of range"]),
    ("huge-int", MOTOR + "max_speed = 10000000000\n", ["motors[0].max_speed", "out of range"]),
    (
        "position-range",
        MOTOR + "[motors.mock]\nendstop_max = 8388608\n",
        ["motors[0].mock.endstop_max = 8388608", "-8388608..8388607"],
    ),
    # cross-key rules
    (
        "default-speed-above-max",
        MOTOR + "max_speed = 1000\ndefault_speed = 1001\n",
        ["motors[0].default_speed = 1001", "out of range", "<= max_speed (max_speed = 1000)"],
    ),
    (
        "default-speed-broken-by-max",
        MOTOR + "max_speed = 1000\n",
        ["motors[0].default_speed = 2000.0", "the default value", "<= max_speed"],
    ),
    (
        "default-accel-above-max",
        MOTOR + "max_accel = 100\ndefault_accel = 50\ndefault_decel = 101\n",
        ["motors[0].default_decel = 101", "<= max_accel (max_accel = 100)"],
    ),
    (
        "homing-speed-above-max",
        MOTOR + "max_speed = 300\ndefault_speed = 1\n"
        "[motors.homing]\nspeed = 100\nsecond_speed = 301\n",
        ["motors[0].homing.second_speed = 301", "<= max_speed (max_speed = 300)"],
    ),
    (
        "soft-limit-min-only",
        MOTOR + "soft_limit_min = -5\n",
        ["motors[0].soft_limit_min = -5", "soft_limit_max is not set", "both", "or neither"],
    ),
    (
        "soft-limit-max-only",
        MOTOR + "soft_limit_max = 5\n",
        ["motors[0].soft_limit_max = 5", "soft_limit_min is not set", "or neither"],
    ),
    (
        "soft-limits-reversed",
        MOTOR + "soft_limit_min = 5\nsoft_limit_max = 5\n",
        ["motors[0].soft_limit_min = 5", "soft_limit_min < soft_limit_max"],
    ),
    (
        "soft-limits-rotary",
        MOTOR + "steps_per_rev = 200\nsoft_limit_min = 0\nsoft_limit_max = 100\n",
        ["motors[0].soft_limit_min = 0", "rotary", "only on a linear axis (steps_per_rev = 0)"],
    ),
    (
        "mock-endstops-reversed",
        MOTOR + "[motors.mock]\nendstop_min = 10\nendstop_max = -10\n",
        ["motors[0].mock.endstop_min = 10", "endstop_min < endstop_max"],
    ),
    (
        "duplicate-pin",
        MOTOR + "[[pins]]\nnumber = 3\n[[pins]]\nnumber = 4\n[[pins]]\nnumber = 3\n",
        ["pins[2].number = 3", "duplicate (pins[0].number is also 3)", "no other [[pins]]"],
    ),
    (
        "duplicate-motor-name",
        MOTOR + '[[motors]]\nname = "motor0"\n',
        ['motors[1].name = "motor0"', "duplicate", "no other [[motors]]"],
    ),
    (
        "pin-number-missing",
        MOTOR + "[[pins]]\nmode = 'input'\n",
        ["pins[0].number: missing", "an integer in 0..255 (required)"],
    ),
    (
        "wire-to-missing-pin",
        MOTOR + PINS_0_TO_3 + "[mock]\nwires = [[0, 1], [2, 9]]\n",
        ["mock.wires[1] = [2, 9]", "pin 9 is not in [[pins]]", "listed in [[pins]]"],
    ),
    (
        "default-wires-missing-pins",
        MOTOR + PINS_0_TO_3 + "[mock]\n",
        ["mock.wires[0] = [0, 4]", "pin 4", "the default value", "listed in [[pins]]"],
    ),
    (
        "pin-in-two-wires",
        MOTOR + PINS_0_TO_3 + "[mock]\nwires = [[0, 1], [2, 1]]\n",
        ["mock.wires[1] = [2, 1]", "pin 1 is also in mock.wires[0]", "at most one wire"],
    ),
    (
        "pin-wired-to-itself",
        MOTOR + PINS_0_TO_3 + "[mock]\nwires = [[2, 2]]\n",
        ["mock.wires[0] = [2, 2]", "pin 2 is also in this wire", "at most one wire"],
    ),
    (
        "unknown-backend",
        '[hal]\nbackend = "stepper9000"\n' + MOTOR,
        ['hal.backend = "stepper9000"', 'one of "mock", "gpiod"'],
    ),
    (
        "unknown-checksum",
        '[link]\nchecksum = "crc16"\n' + MOTOR,
        ['link.checksum = "crc16"', "unknown CRC-8", '"crc8"', '"none"', "CRC-8/MAXIM-DOW"],
    ),
    (
        "bad-motor-name",
        MOTOR + 'name = "x axis"\n',
        ['motors[0].name = "x axis"', "letters, digits"],
    ),
    # paths no system call takes, or that name no file: refused here, not a traceback at start
    (
        "state-directory-nul",
        '[state]\ndirectory = "/run/a\\u0000b"\n' + MOTOR,
        ['state.directory = "/run/a\\u0000b"', "holds a NUL character", "an absolute path"],
    ),
    (
        "trace-file-nul",
        '[trace]\nfile = "/run/a\\u0000.pcapng"\n' + MOTOR,
        ['trace.file = "/run/a\\u0000.pcapng"', "holds a NUL character"],
    ),
    (
        "trace-file-folder",
        '[trace]\nfile = "/run/motorctl/"\n' + MOTOR,
        ['trace.file = "/run/motorctl/": names a folder, not a file', "an absolute path"],
    ),
    (
        "trace-file-dot-dot",
        '[trace]\nfile = "/run/motorctl/.."\n' + MOTOR,
        ['trace.file = "/run/motorctl/..": names a folder, not a file'],
    ),
    ("no-motors", "[link]\n", ["motors: missing", "1..64 [[motors]] tables"]),
    ("zero-motors", "motors = []\n", ["motors: 0 entries", "1..64 [[motors]] tables"]),
    ("too-many-motors", MOTOR * 65, ["motors: 65 entries", "1..64 [[motors]] tables"]),
]


@pytest.mark.parametrize(
    ("text", "fragments"), [(t, f) for _, t, f in ERRORS], ids=[i for i, _, _ in ERRORS]
)
def test_error_messages(text: str, fragments: list[str]) -> None:
    message = error_of(text)
    assert message.startswith(SOURCE + ": ")
    assert "accepted" in message
    for fragment in fragments:
        assert fragment in message


def test_unknown_key_lists_the_schema_keys_of_its_table() -> None:
    for path, type_, _, _ in describe_keys():
        if type_ != "table" or path.startswith(("motors", "pins", "gpiod.dc.")):  # required keys
            continue
        message = error_of(f"[{path}]\nbogus = 1\n" + MOTOR)
        own = sorted(
            p.split(".")[-1]
            for p, *_ in describe_keys()
            if p.startswith(path + ".") and p.count(".") == path.count(".") + 1
        )
        assert message.endswith(f"accepted keys in [{path}]: {', '.join(own)}")


def test_toml_syntax_error_keeps_line_and_column() -> None:
    text = "[link]\nframe_gap_ms = 5\n\nchecksum = crc8\n" + MOTOR
    message = error_of(text)
    assert message.startswith(f"{SOURCE}: line 4: TOML syntax error: ")
    assert "line 4, column" in message


def test_toml_syntax_error_at_end_of_document() -> None:
    message = error_of('[[motors]]\nname = "x')
    assert message.startswith(f"{SOURCE}: line 2: TOML syntax error: ")


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: config file not found")
    assert "fix:" in message


def test_unreadable_and_undecodable_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"is a directory, not a regular file; fix:"):
        load_config(tmp_path)
    path = tmp_path / "latin1.toml"
    path.write_bytes(b"[[motors]]\n# caf\xe9\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}: line 2: not valid UTF-8")


def test_error_from_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(MOTOR + "max_speed = -1\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}: motors[0].max_speed = -1: out of range")


# --- documentation ----------------------------------------------------------------------------


def doc_row(row: tuple[str, str, str, str]) -> str:
    """The markdown table row docs/config.md carries for one describe_keys() row."""
    path, type_, default, accepted = (cell.replace("|", "\\|") for cell in row)
    return f"| `{path}` | {type_} | {default} | {accepted} |"


def test_describe_keys_shape() -> None:
    rows = describe_keys()
    paths = [row[0] for row in rows]
    assert len(paths) == len(set(paths))
    assert all(all(cell for cell in row) for row in rows)
    max_speed = rows[paths.index("motors[].max_speed")]
    assert max_speed[:3] == ("motors[].max_speed", "number", "25000.0")


def test_docs_list_every_key() -> None:
    lines = set(DOCS.read_text(encoding="utf-8").splitlines())
    missing = [row[0] for row in describe_keys() if doc_row(row) not in lines]
    assert missing == [], f"docs/config.md is out of date for: {missing}"


def test_docs_are_generated() -> None:
    assert DOCS.read_text(encoding="utf-8") == render(), (
        "docs/config.md is out of date: run python -m motorctl.daemon.config.docs --write"
    )


def test_docs_mention_check_config() -> None:
    assert "motorctld --check-config" in DOCS.read_text(encoding="utf-8")


# --- owners: backends' sections, the schema engine -----------------------------------------


def test_backend_choices_come_from_the_registry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from motorctl.hal import registry

    (tmp_path / "fake_empty_config.py").write_text(
        "from motorctl.hal.contract import BackendDeclaration\n"
        "class Empty(BackendDeclaration):\n"
        "    def sections(self, drivers):\n"
        "        return ()\n",
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    backends = dict(registry.BACKENDS)
    backends["fake"] = registry.Entry("fake_empty_config:Empty", "no.such:Module", "a fake library")
    monkeypatch.setattr(registry, "BACKENDS", backends)
    assert parse_config('[hal]\nbackend = "fake"\n' + MOTOR, SOURCE).hal.backend == "fake"
    message = error_of('[hal]\nbackend = "gpio"\n' + MOTOR)
    assert 'one of "mock", "gpiod", "fake" (the backends of motorctl.hal.registry)' in message


FAKE_CONFIG = """
from __future__ import annotations
from dataclasses import dataclass
from motorctl.hal.contract import BackendDeclaration, DriverLookup
from motorctl.schema import Extension, integer, section, text

@section("Wiring of the fake backend.")
@dataclass(frozen=True)
class FakeConfig:
    chip: str = text("/dev/gpiochip0", "The chip.", pattern=r"/dev/\\S+", pattern_text="a path")

@section("One motor's fake lines.")
@dataclass(frozen=True)
class FakeAxisConfig:
    step_line: int = integer(0, 0, 511, "STEP line offset.")

class FakeDeclaration(BackendDeclaration):
    def sections(self, drivers: DriverLookup) -> tuple[Extension, ...]:
        return (
            Extension("", "fake", FakeConfig, owner="the fake backend"),
            Extension("motors", "fake", FakeAxisConfig, owner="the fake backend"),
        )
"""


def test_a_backend_registers_its_sections_without_loading_its_library(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A backend's declaration is read to check a config; its implementation's module
    (which would import the hardware library) is not imported."""
    import sys

    from motorctl.hal import registry

    (tmp_path / "fake_backend_config.py").write_text(FAKE_CONFIG, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    backends = dict(registry.BACKENDS)
    backends["fake"] = registry.Entry(
        "fake_backend_config:FakeDeclaration", "fake_backend_hw:FakeBackend", "a fake library"
    )
    monkeypatch.setattr(registry, "BACKENDS", backends)
    config = parse_config(
        '[hal]\nbackend = "fake"\n[fake]\nchip = "/dev/gpiochip4"\n'
        + MOTOR
        + "[motors.fake]\nstep_line = 17\n"
        + MOTOR,
        SOURCE,
    )
    module = sys.modules["fake_backend_config"]
    assert config.section(module.FakeConfig).chip == "/dev/gpiochip4"
    assert [m.section(module.FakeAxisConfig).step_line for m in config.motors] == [17, 0]
    # other backends' sections too
    assert config.section(MockConfig) == MockConfig(lose_steps=False, wires=())
    assert "fake_backend_hw" not in sys.modules
    message = error_of(MOTOR + "[motors.fake]\nstep_line = 512\n")
    assert "motors[0].fake.step_line = 512: out of range; accepted: an integer in 0..511" in message
    message = error_of(MOTOR + "[fake]\nchips = 1\n")
    assert message.endswith("unknown key 'fake.chips'; accepted keys in [fake]: chip")
    rows = {row[0] for row in describe_keys()}
    assert {"fake", "fake.chip", "motors[].fake", "motors[].fake.step_line"} <= rows
    assert "### [fake] (the fake backend)" in render()


def test_checking_a_config_imports_no_backend_module() -> None:
    """Loading a config (even naming the mock) never imports a backend's implementation."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from motorctl.daemon.config import load_config, default_config_text\n"
        "load_config(None); default_config_text()\n"
        "print(sorted(m for m in sys.modules if m.startswith('motorctl.hal.backends.mock.') "
        "and m != 'motorctl.hal.backends.mock.config' or "
        "m.split('.')[0] in ('gpiod', 'spidev', 'systemd')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == "[]"


def test_section_checks_annotations_against_declarations() -> None:
    from dataclasses import dataclass

    from motorctl.schema import integer, number, section

    with pytest.raises(TypeError, match=r"Bad\.x: annotate it `float`"):

        @section("bad")
        @dataclass(frozen=True)
        class Bad:
            x: int = number(1.0, 0, 2, "a number declared as int")

    with pytest.raises(TypeError, match=r"not declared with motorctl\.schema"):

        @section("bad")
        @dataclass(frozen=True)
        class Bad2:
            x: int = integer(1, 0, 2, "fine")
            y: int = 3


def test_checksum_names_agree_with_the_client() -> None:
    """One definition (motorctl.protocol.crc.checksum_by_name) for the config and the CLI."""
    from motorctl.client.cli import build_parser
    from motorctl.protocol.crc import checksum_by_name

    for name in ("none", "NONE", "crc8", "CRC8", "maxim-dow"):
        config = parse_config(f'[link]\nchecksum = "{name}"\n' + MOTOR, SOURCE)
        assert config.link.codec_options().crc == checksum_by_name(name)
    assert checksum_by_name("NONE") is None and checksum_by_name("crc8") == SMBUS
    assert build_parser().parse_args(["ready", "0"]).checksum == "crc8"


def test_trace_is_off_by_default_and_wants_an_absolute_path() -> None:
    assert parse_config(MOTOR, SOURCE).trace == TraceConfig("", 16.0, 4)
    config = parse_config("[trace]\nfile = '/run/x.pcapng'\nfiles = 2\n" + MOTOR, SOURCE)
    assert config.trace.file == "/run/x.pcapng" and config.trace.files == 2
    with pytest.raises(ConfigError, match=r'trace\.file = "x\.pcapng": not an absolute path'):
        parse_config("[trace]\nfile = 'x.pcapng'\n" + MOTOR, SOURCE)


def test_homing_source_is_an_enum() -> None:
    config = parse_config(MOTOR + "[motors.homing]\nsource = 'stall'\n", SOURCE)
    assert config.motors[0].homing.source is HomingSource.STALL


def test_table_of_the_whole_file() -> None:
    spec = schema()
    assert isinstance(spec, Table)
    assert [c.name for c in spec.children] == [
        "link",
        "units",
        "hal",
        "step_thread",
        "state",
        "trace",
        "dc",
        "motors",
        "pins",
        "drivers",
        "mock",
        "gpiod",
        "spidev",
        "dspin",
    ]


def test_mock_position_range_is_the_protocols() -> None:
    from motorctl.hal.backends.mock import config as mock_config
    from motorctl.protocol.codec import POS_MAX, POS_MIN

    assert (mock_config.POSITION_MIN, mock_config.POSITION_MAX) == (POS_MIN, POS_MAX)


def test_old_embedded_default_file_still_loads_the_same() -> None:
    """The embedded default as a file of the last release (daemon/default.toml, every key
    written out) loads to exactly today's embedded default."""
    old = Path(__file__).resolve().parent / "data" / "default-0.2.0.toml"
    assert dataclasses.replace(load_config(old), source="x") == dataclasses.replace(
        load_config(None), source="x"
    )


def test_backends_get_their_sections_in_the_hardware_spec() -> None:
    from motorctl.daemon.start.assemble import hardware_spec

    config = parse_config(
        MOTOR + "[motors.mock]\nendstop_min = -5\n" + PINS_0_TO_3 + "[mock]\nwires = [[0, 1]]\n",
        SOURCE,
    )
    spec = hardware_spec(config)
    assert spec.section(MockConfig).wires == ((0, 1),)
    assert spec.axes[0].section(MockAxisConfig) == MockAxisConfig(-5, 10000, True)
    assert all(pin.section(GpiodPinConfig) is None for pin in spec.pins)  # not wired


def test_motion_defaults_are_the_configs() -> None:
    """motion.types keeps construction defaults for its own tests, but not those of the lag
    rule (start_speed, max_lag_full_steps: declared in the config model only, the tests take
    them from there); the daemon always passes every value from the config
    (daemon.start.assemble.motor_params). They must not drift apart."""
    from motorctl.daemon.start.assemble import motor_params
    from motorctl.motion.types import HomingParams
    from tests.support.motor_defaults import motor_params as declared_params

    built = motor_params(parse_config(MOTOR, SOURCE))[0]
    assert dataclasses.replace(built, name="motor", host_position=None) == declared_params()
    assert built.homing == HomingParams()


def test_a_retired_key_still_loads_with_a_notice_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """max_lateness_us (0.2.0's fail-safe) is accepted with any value and means nothing now:
    the same config as without it, and a notice that says so and what replaced it."""
    from motorctl.daemon.start.main import main

    config = parse_config("[step_thread]\nmax_lateness_us = 2000.0\n" + MOTOR, SOURCE)
    assert config == parse_config(MOTOR, SOURCE) and not parse_config(MOTOR, SOURCE).notices
    (notice,) = config.notices
    assert notice.startswith(f"{SOURCE}: 'step_thread.max_lateness_us' is retired and ignored")
    assert "max_lag_full_steps" in notice and notice.endswith("fix: remove it")
    old = Path(__file__).resolve().parent / "data" / "default-0.2.0.toml"
    assert main(["--check-config", str(old)]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "'step_thread.max_lateness_us' is retired" in err
    # still an unknown key elsewhere, and not offered as an accepted key
    message = error_of("[link]\nmax_lateness_us = 1\n" + MOTOR)
    assert "unknown key 'link.max_lateness_us'" in message
    message = error_of("[step_thread]\nbogus = 1\n" + MOTOR)
    assert "max_lateness_us" not in message


@pytest.mark.parametrize(
    ("old", "key"),
    [
        ("[step_thread]\ndriver_poll_ms = 5.0\n" + MOTOR, "step_thread.driver_poll_ms"),
        (
            MOTOR + '[motors.tmc]\nspi = "/dev/spidev0.1"\npoll_ms = 5.0\n',
            "motors[0].tmc.poll_ms",
        ),
    ],
)
def test_the_old_driver_poll_keys_load_with_a_notice_naming_the_new_one(old: str, key: str) -> None:
    """The two pollers' periods up to f8b0dbb (the engine's, the TMC monitor's) became the
    one poller's, [drivers] poll_ms: an old file still loads, its value ignored, and the
    notice (a warning at start and from --check-config) says what to write instead."""
    config = parse_config(old, SOURCE)
    (notice,) = config.notices
    assert notice.startswith(f"{SOURCE}: '{key}' is retired and ignored: ")
    assert "its period" in notice and "is [drivers] poll_ms; fix: remove it" in notice
    assert config.section(DriversConfig) == parse_config(MOTOR, SOURCE).section(DriversConfig)
    new = parse_config("[drivers]\npoll_ms = 5.0\n" + MOTOR, SOURCE)
    assert new.section(DriversConfig).poll_ms == 5.0 and not new.notices


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (MOTOR, 16),
        (MOTOR + "microsteps = 4\n", 4),
        (MOTOR + "[motors.tmc]\nmicrosteps = 64\n", 64),
        (MOTOR + "microsteps = 64\n[motors.tmc]\nmicrosteps = 64\n", 64),
    ],
)
def test_microsteps_come_from_the_motor_or_its_tmc_table(text: str, expected: int) -> None:
    from motorctl.daemon.start.assemble import motor_params

    params = motor_params(parse_config(text, SOURCE))[0]
    assert params.microsteps == expected and params.max_lag_full_steps == 0.5


@pytest.mark.parametrize(
    ("text", "parts"),
    [
        (MOTOR + "microsteps = 12\n", ["motors[0].microsteps = 12", "not a power of two"]),
        (MOTOR + "microsteps = 512\n", ["motors[0].microsteps = 512", "out of range"]),
        (
            MOTOR + "microsteps = 8\n[motors.tmc]\nmicrosteps = 16\n",
            ["motors[0].microsteps = 8", "sets microsteps = 16", "write it once"],
        ),
        (
            MOTOR + "max_lag_full_steps = 0\n",
            ["motors[0].max_lag_full_steps = 0", "a number > 0 and <= 64"],
        ),
        ("[mock]\nlose_steps = 1\n" + MOTOR, ["mock.lose_steps = 1", "true or false"]),
    ],
)
def test_lateness_keys_are_checked(text: str, parts: list[str]) -> None:
    message = error_of(text)
    for part in parts:
        assert part in message, message


def test_only_the_mock_with_lose_steps_off_spares_its_motors_from_the_lag_rule() -> None:
    """The executor's rule follows the hardware: the mock's simulated motors never lose steps
    unless [mock] lose_steps = true; real backends' motors always may."""
    from motorctl.daemon.start.assemble import hardware_spec
    from motorctl.hal.interfaces import VirtualClock
    from motorctl.hal.registry import open_hardware

    for text, lose in (
        ("", False),
        ("[mock]\nwires = []\nlose_steps = false\n", False),
        ("[mock]\nwires = []\nlose_steps = true\n", True),
    ):
        spec = hardware_spec(parse_config(text + MOTOR, SOURCE))
        hw = open_hardware("mock", spec, VirtualClock())
        try:
            assert hw.motors_lose_steps is lose
        finally:
            hw.close()


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("x = " + "[" * 100_000 + "]" * 100_000 + "\n", "TOML nested too deeply to be read"),
        ("x = " + "{a = " * 5000 + "1" + "}" * 5000 + "\n", "TOML nested too deeply to be read"),
        (
            MOTOR + "queue_depth = " + "9" * 5000 + "\n",
            "TOML that cannot be read (Exceeds the limit (4300 digits) for integer string "
            "conversion)",
        ),
    ],
    ids=["arrays", "inline-tables", "digits"],
)
def test_toml_that_python_cannot_read_is_a_config_error_not_a_traceback(
    text: str, says: str
) -> None:
    """What tomllib raises besides its TOMLDecodeError (a RecursionError, int()'s
    ValueError) is a ConfigError naming the file and the problem, as a bad state file is."""
    message = error_of(text)
    assert message.startswith(f"{SOURCE}: ") and says in message
