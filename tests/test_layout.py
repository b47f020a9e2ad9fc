"""The tree keeps its shape where a room has been put in order (issue 23): its tests mirror
it, file by file, and no module or function of it grows past what a reader takes in.

- Mirrored rooms (``MIRRORED``): every test file of tests/<room>/ is named after the module
  it tests, at the same place (tests/hal/backends/gpiod/test_config.py tests
  hal/backends/gpiod/config.py; ``_e2e``: the same module, against motorctld as a process).
- Sized rooms (``SIZED``): no module over ``MAX_LINES`` lines, no function or method of a
  cyclomatic complexity above ``MAX_COMPLEXITY`` (radon's measure, as the issue measured).

A room joins a tuple when it is in order; the rules then keep it so.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from radon.visitors import ComplexityVisitor, Function

from tests.support import REPO

MIRRORED = ("hal",)
SIZED = ("hal",)
MAX_LINES = 600
MAX_COMPLEXITY = 25
_TEST = re.compile(r"^test_(?P<module>\w+?)(?:_e2e)?\.py$")


def module_tested_by(test: Path) -> Path | None:
    """The module a test file names (tests/<room>/a/test_b.py -> <room>/a/b.py)."""
    m = _TEST.match(test.name)
    if m is None:
        return None
    rel = test.parent.relative_to(REPO / "tests")
    return REPO / rel / f"{m.group('module')}.py"


def _names_a_module(test: Path) -> bool:
    module = module_tested_by(test)
    return module is not None and module.is_file()


@pytest.mark.parametrize("room", MIRRORED)
def test_each_test_file_is_named_after_the_module_it_tests(room: str) -> None:
    tests = sorted((REPO / "tests" / room).rglob("test_*.py"))
    assert len(tests) > 5
    strays = [str(t.relative_to(REPO)) for t in tests if not _names_a_module(t)]
    assert strays == [], f"test files that name no module of {room}/: {strays}"


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


@pytest.mark.parametrize("room", SIZED)
def test_no_module_too_long_and_no_function_too_complex(room: str) -> None:
    long, complex_ = [], []
    for path in sorted((REPO / room).rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        where = str(path.relative_to(REPO))
        lines = source.count("\n")
        if lines > MAX_LINES:
            long.append(f"{where}: {lines} lines")
        complex_ += [
            f"{where} {n}: CC {cc}" for n, cc in complexities(source) if cc > MAX_COMPLEXITY
        ]
    assert long == [], f"modules over {MAX_LINES} lines: {long}"
    assert complex_ == [], f"functions above CC {MAX_COMPLEXITY}: {complex_}"


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
