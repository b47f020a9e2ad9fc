"""The tree keeps its shape where a room has been put in order (issue 23): its tests mirror
it, file by file, and no module or function of it grows past what a reader takes in.

- Mirrored rooms (``MIRRORED``): every test file of tests/<room>/ is named after the module
  it tests, at the same place: ``tests/<room>/<folders>/test_<name>.py`` tests
  ``<room>/<folders>/<name>.py`` (or the package ``<name>/``); a module whose tests are
  many may have more files, each named ``test_<name>_<part>.py`` after the part it holds
  (tests/daemon/status/test_server_subscribe.py: the status server's subscriptions);
  ``_e2e``: the same module, against motorctld as a process on a real PTY
  (tests/daemon/start/test_serve_e2e.py: daemon/start/serve.py). So a newcomer finds a
  module's tests by its path, and a test file's module by its name (tests/conftest.py).
- Sized rooms (``SIZED``): no module over ``MAX_LINES`` lines (Python, and the C of the
  compiled step core), no function or method of a cyclomatic complexity above
  ``MAX_COMPLEXITY`` (radon's measure, as the issue measured), with no exception: the step
  core's hot loop too is read in named steps (``StepCore.step``, issue 33).

Every room is in order now (issue 23): each is in both tuples, and a room the package maps
(pyproject.toml's ``package-dir``) but the tuples leave out fails
:func:`test_every_room_is_mirrored_and_sized`, so a new room is held to the rules too.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
from radon.visitors import ComplexityVisitor, Function

from tests.support import REPO

MIRRORED = ("protocol", "client", "daemon", "motion", "hal")
SIZED = ("protocol", "client", "daemon", "motion", "hal")
MAX_LINES = 600
MAX_COMPLEXITY = 25
#: the sources whose length counts (the compiled step core's C beside the Python)
SOURCES = ("*.py", "*.c", "*.h")


def rooms() -> set[str]:
    """The rooms the package maps (pyproject.toml: ``motorctl.<room>`` = ``<room>``)."""
    with (REPO / "pyproject.toml").open("rb") as f:
        mapping = tomllib.load(f)["tool"]["setuptools"]["package-dir"]
    return {name.removeprefix("motorctl.") for name in mapping if name.startswith("motorctl.")}


def test_every_room_is_mirrored_and_sized() -> None:
    assert rooms() == {"protocol", "client", "daemon", "motion", "hal"}  # read as meant
    assert set(MIRRORED) == rooms() and set(SIZED) == rooms()


def module_tested_by(test: Path) -> Path | None:
    """The module (or package) a test file is named after, None when there is none: the
    longest name first (test_session_end.py: session_end.py before session.py)."""
    rel = test.parent.relative_to(REPO / "tests")
    folder = REPO / rel
    parts = test.stem.removeprefix("test_").split("_")
    for i in range(len(parts), 0, -1):
        name = "_".join(parts[:i])
        for candidate in (folder / f"{name}.py", folder / name / "__init__.py"):
            if candidate.is_file():
                return candidate
    return None


@pytest.mark.parametrize("room", MIRRORED)
def test_each_test_file_is_named_after_the_module_it_tests(room: str) -> None:
    tests = sorted((REPO / "tests" / room).rglob("test_*.py"))
    assert len(tests) >= 3  # the room's tests are found
    strays = [str(t.relative_to(REPO)) for t in tests if module_tested_by(t) is None]
    assert strays == [], f"test files that name no module of {room}/: {strays}"


def test_a_test_file_is_matched_with_its_module() -> None:
    tests = REPO / "tests"
    assert module_tested_by(tests / "daemon" / "link" / "test_session_end.py") == (
        REPO / "daemon" / "link" / "session_end.py"
    )
    assert module_tested_by(tests / "daemon" / "status" / "test_server_subscribe.py") == (
        REPO / "daemon" / "status" / "server.py"
    )
    assert module_tested_by(tests / "daemon" / "start" / "test_serve_e2e.py") == (
        REPO / "daemon" / "start" / "serve.py"
    )
    assert module_tested_by(tests / "daemon" / "test_config.py") == (
        REPO / "daemon" / "config" / "__init__.py"
    )
    assert module_tested_by(tests / "hal" / "backends" / "gpiod" / "test_config.py") == (
        REPO / "hal" / "backends" / "gpiod" / "config.py"
    )
    assert module_tested_by(tests / "motion" / "executors" / "process" / "test_child.py") == (
        REPO / "motion" / "executors" / "process" / "child.py"
    )
    assert module_tested_by(tests / "daemon" / "test_e2e.py") is None  # names no module
    assert module_tested_by(tests / "daemon" / "link" / "test_assemble.py") is None  # not there


def _blocks(functions: list[Function], outer: str = "") -> Iterator[tuple[str, int]]:
    for f in functions:
        name = f"{outer}.{f.name}" if outer else f.fullname
        yield name, f.complexity
        yield from _blocks(f.closures, name)


def complexities(source: str) -> Iterator[tuple[str, int]]:
    """(name, cyclomatic complexity) of every function, method and closure in ``source``
    (radon counts a closure on its own, not in the function around it)."""
    visitor = ComplexityVisitor.from_code(source)
    yield from _blocks(visitor.functions)
    for cls in visitor.classes:
        yield from _blocks(cls.methods)


def too_complex(source: str, allowed: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """The functions of ``source`` above MAX_COMPLEXITY but those ``allowed``."""
    return [
        f"{n}: CC {cc}"
        for n, cc in complexities(source)
        if cc > MAX_COMPLEXITY and n not in allowed
    ]


def sources(room: str) -> list[Path]:
    return sorted(p for pattern in SOURCES for p in (REPO / room).rglob(pattern))


@pytest.mark.parametrize("room", SIZED)
def test_no_module_too_long_and_no_function_too_complex(room: str) -> None:
    long, complex_ = [], []
    for path in sources(room):
        source = path.read_text(encoding="utf-8")
        where = path.relative_to(REPO).as_posix()
        lines = source.count("\n")
        if lines > MAX_LINES:
            long.append(f"{where}: {lines} lines")
        if path.suffix == ".py":
            complex_ += [f"{where} {n}" for n in too_complex(source)]
    assert long == [], f"modules over {MAX_LINES} lines: {long}"
    assert complex_ == [], f"functions above CC {MAX_COMPLEXITY}: {complex_}"


def test_the_sized_rooms_are_read_c_too() -> None:
    found = {p.relative_to(REPO).as_posix() for room in SIZED for p in sources(room)}
    assert {
        "motion/motor.py",
        "motion/executors/step_core.py",
        "motion/executors/csrc/core.c",
    } <= found


SOURCE = """
class A:
    def m(self, x):
        def inner(y):
            if y:
                return 1
            if y > 2:
                return 2
            return 3
        return inner(x)

def f(x):
    return 1 if x else 0
"""


def test_the_measure_sees_functions_methods_and_closures() -> None:
    assert dict(complexities(SOURCE)) == {"f": 2, "A.m": 1, "A.m.inner": 3}


def test_a_function_above_the_limit_is_named() -> None:
    branches = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(MAX_COMPLEXITY))
    method = branches.replace("\n    ", "\n        ")
    source = f"def flat(x):\n{branches}    return -1\n\nclass C:\n    def m(self, x):\n"
    source += "    " + method + "        return 0\n"
    over = f"CC {MAX_COMPLEXITY + 1}"
    assert too_complex(source) == [f"flat: {over}", f"C.m: {over}"]
    assert too_complex(source, {"flat"}) == [f"C.m: {over}"]
