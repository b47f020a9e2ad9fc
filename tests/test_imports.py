"""The package's import graph keeps the rooms' order and the HAL's boundary.

Read from the sources (every ``import`` and ``from ... import``, also those inside
functions, and module names written as strings for ``importlib``), not by importing them:

- the rooms depend one way: client -> protocol <- daemon -> motion -> hal, with
  ``motorctl.schema`` and the namespace root (``__version__``) at the bottom, importing
  nothing of motorctl themselves (README.md, "Architecture");
- nothing outside ``hal/`` imports a backend or a layer (``motorctl.hal.backends``,
  ``motorctl.hal.layers``): the daemon names a backend in its config, the registry alone
  names them and builds them, and what only some hardware can do is asked for through
  ``motorctl.hal.interfaces`` (hal/__init__.py);
- inside ``hal/`` too the registry alone names them: no backend or layer imports another
  (the gpiod backend learns a motor's driver chip through the contract, not from the TMC
  layer), and the public modules (interfaces, contract, spec, ...) import none of them;
- inside ``motion/``, the executors' wing (``motion/executors/``) is entered through its base
  only, and looks no higher than the modules it is handed (see ``EXECUTORS``);
- inside ``daemon/``, the wings keep their order and the top stays on top (see
  ``DAEMON_TOP``, ``DAEMON_START`` and ``DAEMON_WINGS``); the link's pure parts reach no
  file, clock or thread (``PURE``); an optional library is imported only by the modules
  that need it (``OPTIONAL``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
ROOMS = ("protocol", "client", "daemon", "motion", "hal")
#: what each room may import besides itself ("root": motorctl/__init__.py and the modules
#: beside it, such as dataclass_code.py, "schema": motorctl/schema/)
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
#: what only hal/ imports: the backends and the layers (hal/registry.py names them)
HIDDEN = ("motorctl.hal.backends.", "motorctl.hal.layers.")
REGISTRY = "motorctl.hal.registry"
#: a module's name written as a string: "motorctl.a.b", or "motorctl.a.b:Class" (the registry)
_MODULE_NAME = re.compile(r"^(motorctl(?:\.[A-Za-z_][A-Za-z0-9_]*)+)(?::[A-Za-z_]\w*)?$")
#: The executors' wing and its one door. The motor state machines (motion/motor.py) and the
#: engine (motion/engine.py), and whatever else of motion/ is outside the wing, know an
#: executor only by its contract, motion/executors/base.py (``Executor``, its events and
#: records): which executor runs (a thread, a process, a driver chip's ramp, a split) is the
#: assembler's choice (daemon/start/assemble.py), and what changes behind the seam (the planner,
#: the step cores, the shared block's rings) never reaches the state machines. The wing in
#: turn imports nothing of the state machines: it carries out plans, it does not make them.
EXECUTORS = "motorctl.motion.executors"
EXECUTORS_BASE = "motorctl.motion.executors.base"
#: what of motion/ the wing must not import (it is handed plans, not the state machines)
ABOVE_EXECUTORS = ("motorctl.motion.motor", "motorctl.motion.engine")
#: What builds and runs the daemon, in order: the motorctld command starts the command line,
#: which hands a daemon to serve to the serve module, which has the assembler build it. Each
#: imports only those after it, and nothing else of the daemon imports any of them: the parts
#: are built and run, they do not build or run one another (a part that needs an error of the
#: start raises daemon/errors.py's, which is below them all).
DAEMON_TOP = (
    "motorctl.daemon.start.launch",
    "motorctl.daemon.start.main",
    "motorctl.daemon.start.serve",
    "motorctl.daemon.start.assemble",
)
#: The package of the start-up chain: the top above and what only it uses (the platform check,
#: the stop signals, the start's timeline, the link's optional parts). Nothing of the daemon
#: outside it imports it, so daemon/'s root shows the jobs it builds and runs.
DAEMON_START = "motorctl.daemon.start"
#: The daemon's wings and the other wings each may import. state/ is the lowest and imports
#: nothing of the daemon outside itself: what the daemon keeps on disk, and the rule of every
#: path it writes (state/files.py), which the link's recorder and ports and the status socket
#: use too. The link reads the state wing's files only; the status wing reads the link and
#: the state, and nothing reads the status back (a part that wants its subscribers to look
#: is handed the server's ``poke``).
DAEMON_WINGS: dict[str, set[str]] = {
    "motorctl.daemon.state": set(),
    "motorctl.daemon.link": {"motorctl.daemon.state"},
    "motorctl.daemon.status": {"motorctl.daemon.state", "motorctl.daemon.link"},
}
#: The link's pure parts: bytes and times in, answers out (pymodbus's framer, Klipper's
#: host-side serial queue), so tests drive them on any clock with any split of the bytes.
#: They import none of the standard library's ways to a file, a clock or a thread, and of
#: motorctl only the protocol and the dispatcher's types.
PURE = ("motorctl.daemon.link.session", "motorctl.daemon.link.silence")
REACHES_OUT = {
    "os",
    "io",
    "select",
    "selectors",
    "socket",
    "threading",
    "time",
    "signal",
    "subprocess",
    "fcntl",
    "termios",
    "ctypes",
    "mmap",
    "multiprocessing",
    "asyncio",
    "pathlib",
}
PURE_MAY_IMPORT = ("motorctl.protocol", "motorctl.daemon.dispatcher")
#: An optional library (a package extra) and the modules that import it, each of which does:
#: the daemon and the rest of the package run without it.
OPTIONAL = {
    "rich": (  # the live monitor's view, its layout and its screen (not its entry point)
        "motorctl.daemon.status.monitor_view",
        "motorctl.daemon.status.monitor_layout",
        "motorctl.daemon.status.monitor_screen",
    ),
    "prometheus_client": ("motorctl.daemon.status.metrics",),
    "spidev": ("motorctl.hal.spi",),  # py-spidev: the HAL's SPI buses, for every layer
}


def package_modules() -> dict[str, Path]:
    """Every module of the package by its name (the rooms as installed: motorctl.<room>)."""
    found = {"motorctl": REPO / "motorctl" / "__init__.py"}
    for path in sorted((REPO / "motorctl").glob("*.py")):  # the root's modules beside it
        if path.stem != "__init__":
            found[f"motorctl.{path.stem}"] = path
    for folder in (*(REPO / room for room in ROOMS), REPO / "motorctl" / "schema"):
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder.parent).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(("motorctl", *parts))] = path
    return found


def in_package(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def wing_problem(name: str, target: str) -> str | None:
    """What breaks the executors' wing's boundary (``EXECUTORS``), None when nothing."""
    inside, there = in_package(name, EXECUTORS), in_package(target, EXECUTORS)
    if room_of(name) == "motion" and not inside and there and target != EXECUTORS_BASE:
        return (
            f"{name} imports {target}: outside motion/executors/, an executor is known by "
            f"its contract only ({EXECUTORS_BASE})"
        )
    if inside and any(in_package(target, above) for above in ABOVE_EXECUTORS):
        return f"{name} imports {target}: the executors carry out plans, they do not make them"
    return None


def wing_of(module: str) -> str | None:
    """The daemon's wing a module is in (``motorctl.daemon.link``, ...), None: none."""
    return next((w for w in DAEMON_WINGS if in_package(module, w)), None)


def daemon_problem(name: str, target: str) -> str | None:
    """What breaks the daemon's inner order (``DAEMON_TOP``, ``DAEMON_WINGS``), or None."""
    if not (in_package(name, "motorctl.daemon") and in_package(target, "motorctl.daemon")):
        return None
    if target in DAEMON_TOP and (
        name not in DAEMON_TOP or DAEMON_TOP.index(target) <= DAEMON_TOP.index(name)
    ):
        return (
            f"{name} imports {target}: the daemon's top imports only down its order "
            f"{' -> '.join(DAEMON_TOP)}, and no part imports it"
        )
    if in_package(target, DAEMON_START) and not in_package(name, DAEMON_START):
        return (
            f"{name} imports {target}: nothing of the daemon outside the start-up chain "
            f"({DAEMON_START}) imports it"
        )
    here, there = wing_of(name), wing_of(target)
    if here is None or here == there:
        return None
    if there is None and here == "motorctl.daemon.state":
        return f"{name} imports {target}: the state wing imports nothing of the daemon outside it"
    if there is not None and there not in DAEMON_WINGS[here]:
        return f"{name} imports {target}: against the wings' order state <- link <- status"
    return None


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
            named = _MODULE_NAME.match(node.value)
            if named:
                found.add(named.group(1))
    return {m for m in found if m == "motorctl" or m.startswith("motorctl.")}


def package_of(module: str) -> str | None:
    """The backend or layer a module belongs to (``motorctl.hal.backends.gpiod``), if any."""
    parts = module.split(".")
    if module.startswith(HIDDEN) and len(parts) >= 4:
        return ".".join(parts[:4])
    return None


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
            if target.startswith(HIDDEN) and here != "hal":
                out.append(
                    f"{name} imports the backend or layer module {target}: ask the HAL's "
                    "registry and interfaces instead"
                )
            elif (
                target.startswith(HIDDEN)
                and package_of(name) != package_of(target)
                and name != REGISTRY
            ):
                out.append(
                    f"{name} imports {target}, of another backend or layer: only "
                    f"{REGISTRY} names them; what one needs of another goes through "
                    "motorctl.hal.contract"
                )
            elif there != here and there not in ALLOWED[here]:
                out.append(
                    f"{name} ({here}) imports {target} ({there}): against the rooms' "
                    "order client -> protocol <- daemon -> motion -> hal"
                )
            elif problem := wing_problem(name, target) or daemon_problem(name, target):
                out.append(problem)
    return out


def outside_imports(source: str) -> set[str]:
    """The first names of the modules ``source`` imports that are not motorctl's (the
    standard library's, a third party's), also inside functions."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return {m for m in found if m != "motorctl"}


def pure_problems(modules: dict[str, str]) -> list[str]:
    """What of ``PURE`` reaches a file, a clock or a thread, or more of motorctl than it may."""
    known = set(modules)
    out = []
    for name in PURE:
        source = modules.get(name, "")
        for lib in sorted(outside_imports(source) & REACHES_OUT):
            out.append(
                f"{name} imports {lib}: the link's pure parts reach no file, clock or thread"
            )
        for target in sorted(imports_of(source, known) & known):  # not logger names
            if not any(in_package(target, ok) for ok in PURE_MAY_IMPORT):
                out.append(f"{name} imports {target}: a pure part imports only {PURE_MAY_IMPORT}")
    return out


def optional_problems(modules: dict[str, str]) -> list[str]:
    """Where an optional library (``OPTIONAL``) is imported by another module than its own."""
    return [
        f"{name} imports {lib}, an optional library only {', '.join(OPTIONAL[lib])} import"
        for name, source in sorted(modules.items())
        for lib in sorted(outside_imports(source) & set(OPTIONAL))
        if name not in OPTIONAL[lib]
    ]


def test_the_package_keeps_the_rooms_order_and_the_hal_boundary() -> None:
    modules = {name: path.read_text(encoding="utf-8") for name, path in package_modules().items()}
    assert {room_of(m) for m in modules} == {*ROOMS, "root", "schema"}  # the whole package
    assert {
        "motorctl.daemon.start.assemble",
        "motorctl.hal.layers.tmc.tmc5160",
        "motorctl.motion.motor",
        "motorctl.motion.engine",
        EXECUTORS_BASE,
        "motorctl.motion.executors.process.parent",
    } <= set(modules)
    assert {*DAEMON_TOP, *PURE, *(m for names in OPTIONAL.values() for m in names)} <= set(modules)
    assert {wing_of(m) for m in modules} == {*DAEMON_WINGS, None}  # every wing has modules
    assert violations(modules) == []


def test_the_links_pure_parts_reach_no_file_clock_or_thread() -> None:
    modules = {name: path.read_text(encoding="utf-8") for name, path in package_modules().items()}
    assert pure_problems(modules) == []


def test_an_optional_library_is_imported_by_its_modules_only() -> None:
    modules = {name: path.read_text(encoding="utf-8") for name, path in package_modules().items()}
    assert optional_problems(modules) == []
    for lib, names in OPTIONAL.items():  # a rule kept for a module that no longer needs it: out
        for name in names:
            assert lib in outside_imports(modules[name]), f"{name} no longer imports {lib}"


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
            "from motorctl.hal.backends.mock.world import MockHardware\n",
            "imports the backend or layer module motorctl.hal.backends.mock.world",
        ),
        (
            "motorctl.motion.x",
            "def f():\n    from motorctl.hal.layers.tmc import tmc5160\n",
            "imports the backend or layer module motorctl.hal.layers.tmc.tmc5160",
        ),
        (
            "motorctl.daemon.x",
            "import importlib\nimportlib.import_module('motorctl.hal.backends.gpiod.backend')\n",
            "imports the backend or layer module motorctl.hal.backends.gpiod.backend",
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
        (
            "motorctl.hal.backends.gpiod.config",
            "from motorctl.hal.layers.tmc.config import TmcAxisConfig\n",
            "imports motorctl.hal.layers.tmc.config, of another backend or layer",
        ),
        (
            "motorctl.hal.interfaces",
            "X = 'motorctl.hal.backends.mock.backend:MockBackend'\n",
            "imports motorctl.hal.backends.mock.backend, of another backend or layer",
        ),
        (
            "motorctl.motion.motor",
            "from motorctl.motion.executors.thread import ThreadStepExecutor\n",
            "motorctl.motion.motor imports motorctl.motion.executors.thread: outside",
        ),
        (
            "motorctl.motion.engine",
            "def f():\n    from motorctl.motion.executors.process import parent\n",
            "motorctl.motion.engine imports motorctl.motion.executors.process.parent",
        ),
        (
            "motorctl.motion.engine",
            "from motorctl.motion import executors\n",
            "motorctl.motion.engine imports motorctl.motion.executors: outside",
        ),
        (
            "motorctl.motion.executors.planner",
            "from motorctl.motion.motor import Motor\n",
            "the executors carry out plans, they do not make them",
        ),
        (
            "motorctl.daemon.link.ports",
            "from motorctl.daemon.start.assemble import StartupError\n",
            "motorctl.daemon.link.ports imports motorctl.daemon.start.assemble: the daemon's top",
        ),
        (
            "motorctl.daemon.start.assemble",
            "def f():\n    from motorctl.daemon.start.serve import run\n",
            "motorctl.daemon.start.assemble imports motorctl.daemon.start.serve: the daemon's top",
        ),
        (
            "motorctl.daemon.link.loop",
            "from motorctl.daemon.start.signals import StopSignals\n",
            "motorctl.daemon.link.loop imports motorctl.daemon.start.signals: nothing of the",
        ),
        (
            "motorctl.daemon.state.journal",
            "from motorctl.daemon.link.loop import Link\n",
            "against the wings' order state <- link <- status",
        ),
        (
            "motorctl.daemon.link.loop",
            "from motorctl.daemon.status.server import StatusServer\n",
            "against the wings' order state <- link <- status",
        ),
        (
            "motorctl.daemon.state.records",
            "from motorctl.daemon.config import Config\n",
            "the state wing imports nothing of the daemon outside it",
        ),
    ],
)
def test_a_wrong_import_is_named(name: str, source: str, says: str) -> None:
    known = {
        "motorctl.hal.spec",
        "motorctl.daemon.config",
        "motorctl.hal.layers.tmc.tmc5160",
        "motorctl.motion.executors",
        "motorctl.motion.executors.thread",
        "motorctl.motion.executors.process",
        "motorctl.motion.executors.process.parent",
    }
    modules = {name: source, **{k: "" for k in known}}
    found = violations(modules)
    assert len(found) == 1 and says in found[0], found


@pytest.mark.parametrize(
    ("source", "says"),
    [
        ("import select\n", "imports select: the link's pure parts reach no file"),
        ("def f():\n    import time\n", "imports time: the link's pure parts reach no file"),
        ("from motorctl.motion.engine import MotionEngine\n", "a pure part imports only"),
    ],
)
def test_a_pure_part_that_reaches_out_is_named(source: str, says: str) -> None:
    known = {"motorctl.motion.engine": ""}
    found = pure_problems({"motorctl.daemon.link.session": source, **known})
    assert len(found) == 1 and says in found[0], found


def test_an_optional_library_elsewhere_is_named() -> None:
    modules = {"motorctl.daemon.start.main": "def f():\n    from rich.console import Console\n"}
    assert optional_problems(modules) == [
        "motorctl.daemon.start.main imports rich, an optional library only "
        "motorctl.daemon.status.monitor_view, motorctl.daemon.status.monitor_layout, "
        "motorctl.daemon.status.monitor_screen import"
    ]
    assert optional_problems({"motorctl.daemon.status.monitor_view": "import rich\n"}) == []
    assert optional_problems({"motorctl.daemon.status.monitor_screen": "import rich\n"}) == []
    # the monitor's entry point says what to install without rich: it does not import it
    assert optional_problems({"motorctl.daemon.status.monitor": "import rich\n"}) != []


def test_what_is_allowed_is_not_named() -> None:
    modules = {
        "motorctl.daemon.x": "from motorctl.hal.registry import open_hardware\n"
        "from motorctl.motion.engine import MotionEngine\n"
        "from motorctl.protocol.codec import wrap24\n"
        "from motorctl import __version__\n",
        "motorctl.hal.backends.mock.world": "from motorctl.hal.backends.mock.config import "
        "MockConfig\nfrom motorctl.schema import table\n",
        "motorctl.hal.registry": "BACKENDS = {'mock': 'motorctl.hal.backends.mock.world:W'}\n",
        "motorctl.hal.layers.tmc.layer": "from motorctl.hal.layers.tmc import config\n",
        "motorctl.motion.x": '"""Prose: :class:`motorctl.hal.layers.tmc.tmc5160.Tmc5160`."""\n',
        "motorctl.motion.motor": "from motorctl.motion.executors.base import Executor\n",
        "motorctl.motion.executors.thread": "from motorctl.motion.executors.planner import "
        "StepExecutor\nfrom motorctl.motion.profile import Trajectory\n",
        "motorctl.daemon.start.assemble": "from motorctl.motion.executors.thread import "
        "ThreadStepExecutor\n",
        "motorctl.daemon.start.main": "from motorctl.daemon.start.serve import serve\n",
        "motorctl.daemon.start.serve": "from motorctl.daemon.start.assemble import build_served\n",
        "motorctl.daemon.status.document": "from motorctl.daemon.link.loop import Link\n"
        "from motorctl.daemon.state.persistence import Persistence\n"
        "from motorctl.daemon.config import Config\n",
        "motorctl.daemon.link.ports": "from motorctl.daemon.state import files\n"
        "from motorctl.daemon.errors import StartupError\n",
    }
    assert violations(modules) == []
