"""The package's import graph keeps the rooms' order and the HAL's boundary.

Read from the sources (every ``import`` and ``from ... import``, also those inside
functions, and module names written as strings for ``importlib``), not by importing them:

- the rooms depend one way: client -> protocol <- daemon -> motion -> hal, with
  ``motorctl.schema`` and the namespace root (``__version__``) at the bottom, importing
  nothing of motorctl themselves (README.md, "Architecture");
- nothing outside ``hal/`` imports a backend (``motorctl.hal.backends``): the daemon names a
  backend in its config, the registry builds it, and what only some hardware can do is asked
  for through ``motorctl.hal.interfaces`` (hal/__init__.py).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
ROOMS = ("protocol", "client", "daemon", "motion", "hal")
#: what each room may import besides itself ("root": motorctl/__init__.py, "schema":
#: motorctl/schema.py)
ALLOWED = {
    "root": set(),
    "schema": set(),
    "protocol": {"root", "schema"},
    "client": {"root", "schema", "protocol"},
    "daemon": {"root", "schema", "protocol", "motion", "hal"},
    "motion": {"root", "schema", "hal"},
    "hal": {"root", "schema"},
}
#: The one import against the rooms' order, with its reason. ``motorctl monitor`` (the
#: client's CLI) runs the daemon's live monitor, which reads the daemon's status socket on
#: the daemon's machine and is the same view as ``motorctld --status --watch``; the status
#: socket's format is the daemon's own. The CLI imports it lazily, only for that command, so
#: the client library and every other command load nothing of the daemon.
EXCEPTIONS = {("motorctl.client.cli", "motorctl.daemon.status.monitor")}
BACKENDS = "motorctl.hal.backends"
_MODULE_NAME = re.compile(r"^motorctl(\.[A-Za-z_][A-Za-z0-9_]*)+$")


def package_modules() -> dict[str, Path]:
    """Every module of the package by its name (the rooms as installed: motorctl.<room>)."""
    found = {
        "motorctl": REPO / "motorctl" / "__init__.py",
        "motorctl.schema": REPO / "motorctl" / "schema.py",
    }
    for room in ROOMS:
        for path in sorted((REPO / room).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(("motorctl", *parts))] = path
    return found


def room_of(module: str) -> str:
    """The room of a motorctl module: its first name below motorctl ("root" for motorctl)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in (*ROOMS, "schema") else "root"


def _docstrings(tree: ast.Module) -> set[int]:
    """ids of the docstring nodes (names in prose are no imports)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def imports_of(source: str, known: set[str]) -> set[str]:
    """The motorctl modules a module's source imports. ``from A import B`` is A.B when that
    is a module (``known``), else A; a string constant that is a dotted motorctl module name
    (importlib) counts, prose in docstrings does not."""
    tree = ast.parse(source)
    prose = _docstrings(tree)
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in known else node.module)
        elif (
            isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in prose
        ):
            for line in node.value.splitlines():
                m = re.match(r"\s*(?:from|import)\s+(motorctl[\w.]*)", line)
                if m:
                    found.add(m.group(1))
            if _MODULE_NAME.match(node.value):
                found.add(node.value)
    return {m for m in found if m == "motorctl" or m.startswith("motorctl.")}


def violations(modules: dict[str, str]) -> list[str]:
    """What breaks the rules, given each module's name and source."""
    known = set(modules)
    out = []
    for name, source in sorted(modules.items()):
        here = room_of(name)
        for target in sorted(imports_of(source, known)):
            there = room_of(target)
            if (name, target) in EXCEPTIONS:
                continue
            if target.startswith(BACKENDS) and here != "hal":
                out.append(
                    f"{name} imports the backend module {target}: ask the HAL's "
                    "registry and interfaces instead"
                )
            elif there != here and there not in ALLOWED[here]:
                out.append(
                    f"{name} ({here}) imports {target} ({there}): against the rooms' "
                    "order client -> protocol <- daemon -> motion -> hal"
                )
    return out


def test_the_package_keeps_the_rooms_order_and_the_hal_boundary() -> None:
    modules = {name: path.read_text(encoding="utf-8") for name, path in package_modules().items()}
    assert {room_of(m) for m in modules} == {*ROOMS, "root", "schema"}  # the whole package
    assert {"motorctl.daemon.assemble", "motorctl.hal.backends.tmc.ramp"} <= set(modules)
    assert violations(modules) == []


def test_the_one_exception_is_still_there() -> None:
    """An exception that no longer exists is removed from the list, not kept for later."""
    modules = package_modules()
    known = set(modules)
    for name, target in EXCEPTIONS:
        assert target in imports_of(modules[name].read_text(encoding="utf-8"), known)


@pytest.mark.parametrize(
    ("name", "source", "says"),
    [
        (
            "motorctl.daemon.x",
            "from motorctl.hal.backends.mock.backend import MockHardware\n",
            "imports the backend module motorctl.hal.backends.mock.backend",
        ),
        (
            "motorctl.motion.x",
            "def f():\n    from motorctl.hal.backends.tmc import ramp\n",
            "imports the backend module motorctl.hal.backends.tmc.ramp",
        ),
        (
            "motorctl.daemon.x",
            "import importlib\nimportlib.import_module('motorctl.hal.backends.gpiod.backend')\n",
            "imports the backend module motorctl.hal.backends.gpiod.backend",
        ),
        (
            "motorctl.hal.x",
            "from motorctl.motion.engine import MotionEngine\n",
            "motorctl.hal.x (hal) imports motorctl.motion.engine (motion)",
        ),
        (
            "motorctl.motion.x",
            "from motorctl.daemon import config\n",
            "motorctl.motion.x (motion) imports motorctl.daemon.config (daemon)",
        ),
        (
            "motorctl.protocol.x",
            "import motorctl.client.client\n",
            "motorctl.protocol.x (protocol) imports motorctl.client.client (client)",
        ),
        (
            "motorctl.client.x",
            "from motorctl.daemon.status.server import read_status\n",
            "motorctl.client.x (client) imports motorctl.daemon.status.server (daemon)",
        ),
        (
            "motorctl.schema",
            "from motorctl.hal import spec\n",
            "motorctl.schema (schema) imports motorctl.hal.spec (hal)",
        ),
    ],
)
def test_a_wrong_import_is_named(name: str, source: str, says: str) -> None:
    known = {"motorctl.hal.spec", "motorctl.daemon.config", "motorctl.hal.backends.tmc.ramp"}
    modules = {name: source, **{k: "" for k in known}}
    found = violations(modules)
    assert len(found) == 1 and says in found[0], found


def test_what_is_allowed_is_not_named() -> None:
    modules = {
        "motorctl.daemon.x": "from motorctl.hal.registry import open_hardware\n"
        "from motorctl.motion.engine import MotionEngine\n"
        "from motorctl.protocol.codec import wrap24\n"
        "from motorctl import __version__\n",
        "motorctl.hal.backends.mock.backend": "from motorctl.hal.backends.mock.config import "
        "MockConfig\nfrom motorctl.schema import table\n",
        "motorctl.hal.registry": "BACKENDS = {'mock': 'motorctl.hal.backends.mock.backend'}\n",
        "motorctl.motion.x": '"""Prose: :class:`motorctl.hal.backends.tmc.ramp.Tmc5160`."""\n',
    }
    assert violations(modules) == []
