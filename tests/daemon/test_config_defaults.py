"""Each setting's default is written once (issue 33, "every default in one place").

The scan reads the source with `ast`: every key the config schema declares (every table,
every backend's and layer's section) against every place a value is written as a default — a
dataclass field, a function parameter's default, a module constant — in client/, daemon/,
motion/, hal/ and protocol/. A place counts for a setting when it has the setting's name (its
unit suffix aside: `spin_us` and `spin_s` are one quantity) and either its default (in the
same unit) or, for a name with a unit, any literal at all (a second value is a
disagreement, as `ahead_s` once was). The declaration itself is one place; any other fails.

A runtime record that needs the value reads it from the declaration (or the declaration
from the record's constant), as `[step_thread] stop_confirm_ms` reads `STOP_CONFIRM_S`.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from motorctl.daemon.config import schema
from motorctl.schema import REQUIRED, Table
from tests.support import REPO

ROOMS = ("client", "daemon", "motion", "hal", "protocol")
UNITS = {"us": 1e-6, "ms": 1e-3, "s": 1.0}
#: the schema's key helpers: `name: T = number(DEFAULT, ...)` declares a key
HELPERS = {"integer", "number", "boolean", "choice", "text"}

#: where a default is written again on purpose, with why: (file, name) -> reason
AGAIN = {
    # motion may not import the daemon (the rooms' order): motion/types.py restates the
    # motor's and homing's settings, and tests/motion/test_types.py keeps them equal
    ("motion/types.py", "max_travel"): "HomingParams, kept equal by tests/motion/test_types.py",
    ("motion/types.py", "pull_off"): "HomingParams, kept equal by tests/motion/test_types.py",
    ("motion/types.py", "second_speed"): "HomingParams, kept equal by tests/motion/test_types.py",
    ("motion/types.py", "debounce_s"): "MotorParams, kept equal by tests/motion/test_types.py",
    ("motion/types.py", "dir_setup_s"): "MotorParams, kept equal by tests/motion/test_types.py",
    # the state wing may not import the config (tests/test_imports.py); assemble.py passes
    # each motor's steps_per_rev, the record's default serves its tests
    ("daemon/state/records.py", "steps_per_rev"): "MotorIdentity of the state file",
    # named like a setting, another quantity
    ("hal/dspin/status.py", "active_low"): "a dSPIN status flag's polarity, not an end stop's",
    ("hal/backends/gpiod/chip.py", "debounce_us"): "a line request's field (0: none); an end "
    "stop's request passes the motor's [motors.endstop] debounce_ms",
    ("motion/executors/chip_ramp.py", "position"): "an axis's last read position, not "
    "[motors.dspin] position (a place in the chain)",
    # two chip families' own settings, each written once, equal by chance: [motors.tmc]
    # microsteps in hal/layers/tmc/settings.py
    ("hal/layers/dspin/config.py", "microsteps"): "[motors.dspin] microsteps, the dSPIN's "
    "own (STEP_SEL), equal to the TMC layer's by chance",
    ("hal/interfaces.py", "poll_s"): "RampDriver's poll, the one default of [spidev] "
    "ramp_poll_ms, named like [drivers] poll_ms",
}


def _canon(name: str) -> tuple[str, float | None]:
    """(the name without its unit, the unit in seconds, or None when it has none)."""
    base, _, unit = name.rpartition("_")
    return (base, UNITS[unit]) if base and unit in UNITS else (name, None)


@dataclass(frozen=True)
class Setting:
    table: str
    key: str
    default: Any


@dataclass(frozen=True)
class Site:
    where: str
    name: str
    value: Any


def declared(table: Table | None = None) -> Iterator[Setting]:
    """Every key with a default (a number, a flag or a string) of the whole schema."""
    table = table or schema()
    for key in table.keys:
        value = getattr(key.default, "value", key.default)  # an enum's member: its value
        if value is not REQUIRED and isinstance(value, (bool, int, float, str)):
            yield Setting(table.cls.__name__, key.name, value)
    for child in table.children:
        yield from declared(child.table)


def _literal(node: ast.expr | None) -> Any:
    if node is None:
        return None
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) in HELPERS and node.args:
        node = node.args[0]
    try:
        value = ast.literal_eval(node)
    except ValueError:
        return None
    return value if isinstance(value, (bool, int, float, str)) else None


def sites(source: str, where: str) -> Iterator[Site]:
    """Every default written as a literal in ``source``: dataclass fields (and the schema's
    declarations), parameters' defaults, module constants (by their lower-case name)."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        named: list[tuple[str, ast.expr | None]] = []
        if isinstance(node, ast.ClassDef):
            named += [
                (n.target.id, n.value)
                for n in node.body
                if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
            ]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            positional = a.posonlyargs + a.args
            named += [
                (arg.arg, d)
                for arg, d in zip(
                    positional[len(positional) - len(a.defaults) :], a.defaults, strict=True
                )
            ]
            named += [(arg.arg, d) for arg, d in zip(a.kwonlyargs, a.kw_defaults, strict=True)]
        elif isinstance(node, ast.Module):
            for n in node.body:
                targets = n.targets if isinstance(n, ast.Assign) else []
                if isinstance(n, ast.AnnAssign):
                    targets = [n.target]
                named += [
                    (t.id.lower(), n.value)  # type: ignore[attr-defined]
                    for t in targets
                    if isinstance(t, ast.Name) and t.id.isupper()
                ]
        for name, value_node in named:
            value = _literal(value_node)
            if value is not None:
                yield Site(where, name, value)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str):
        return type(a) is type(b) and a == b
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-15)


def counts(site: Site, setting: Setting) -> bool:
    """Whether ``site`` writes ``setting``'s default (or, with a unit, another value)."""
    base, unit = _canon(site.name)
    key_base, key_unit = _canon(setting.key)
    if base != key_base:
        return False
    if unit is not None and key_unit is not None:
        return True  # the same quantity: its default written again, or a second one
    return unit is None and key_unit is None and _same(site.value, setting.default)


def _scale(site: Site, setting: Setting) -> Any:
    unit, key_unit = _canon(site.name)[1], _canon(setting.key)[1]
    if unit is None or key_unit is None or isinstance(site.value, (bool, str)):
        return site.value
    return site.value * unit / key_unit


def restated(paths: list[tuple[str, str]]) -> dict[str, list[str]]:
    """setting -> the places that write its default, where more than one does (each with
    the value in the setting's unit)."""
    return restated_sites([site for source, where in paths for site in sites(source, where)])


def restated_sites(found_sites: list[Site]) -> dict[str, list[str]]:
    """``restated`` of sites already found (the whole checkout's are parsed once)."""
    by_base: dict[str, list[Setting]] = {}
    for s in declared():
        by_base.setdefault(_canon(s.key)[0], []).append(s)
    found: dict[str, list[str]] = {}
    for site in found_sites:
        where = site.where
        # only a setting of the same name (its unit aside) can count: `counts` checks first
        for s in by_base.get(_canon(site.name)[0], []):
            if counts(site, s) and (where, site.name) not in AGAIN:
                v = _scale(site, s)
                found.setdefault(f"{s.table}.{s.key} = {s.default!r}", []).append(
                    f"{where}: {site.name} ({v!r})"
                )
    return {k: v for k, v in found.items() if len(v) > 1}


def _sources() -> list[tuple[str, str]]:
    return [
        (p.read_text(encoding="utf-8"), p.relative_to(REPO).as_posix())
        for room in ROOMS
        for p in sorted((REPO / room).rglob("*.py"))
    ]


def test_each_settings_default_is_written_once() -> None:
    found = [site for source, where in _sources() for site in sites(source, where)]
    again = restated_sites(found)
    assert again == {}, "\n".join(f"{k}: {', '.join(v)}" for k, v in again.items())
    seen = {(site.where, site.name) for site in found}
    assert set(AGAIN) <= seen  # no reason kept for a place that is gone


def test_the_scan_sees_every_section() -> None:
    tables = {s.table for s in declared()}
    assert {"StepThreadConfig", "TmcAxisConfig", "GpiodPwmConfig", "MockAxisConfig"} <= tables


SPIN = "    spin_us: float = number(200.0, 0, 100000, 'Sleep, then spin.')\n"


@pytest.mark.parametrize(
    ("again", "what"),
    [
        ("def f(*, spin_s: float = 200e-6) -> None: ...\n", "a parameter in another unit"),
        ("def f(spin_us: float = 200.0) -> None: ...\n", "a parameter"),
        ("class A:\n    spin_s: float = 0.0002\n", "a field"),
        ("SPIN_US = 200.0\n", "a constant"),
        ("def f(*, ahead_s: float = 0.02) -> None: ...\n", "another value, in a unit"),
        ("class T:\n    toff: int = 3\n", "a name without a unit, the same value"),
    ],
)
def test_a_default_written_again_is_seen(again: str, what: str) -> None:
    declaring = (
        "class StepThreadConfig:\n" + SPIN + "    ahead_ms: float = number(50.0)\n"
        "class TmcAxisConfig:\n    toff: int = integer(3, 1, 15, 'TOFF.')\n"
    )
    assert len(list(sites(declaring, "daemon/config/model.py"))) == 3
    assert restated([(declaring, "daemon/config/model.py")]) == {}
    found = restated([(declaring, "daemon/config/model.py"), (again, "motion/x.py")])
    assert len(found) == 1, what


def test_a_name_without_a_unit_and_another_value_is_not_the_setting() -> None:
    assert restated([("def f(timeout: float = 5.0) -> None: ...\n", "client/x.py")]) == {}
    assert restated([("class T:\n    toff: int = 4\n", "hal/x.py")]) == {}
