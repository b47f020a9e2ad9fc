"""Every dataclass of the package has a docstring (docs/timing.md, issue 36).

Python 3.11's ``@dataclass`` gives a class without one a ``__doc__`` built from
``inspect.signature`` of the class, at every import: tens of microseconds a class, for a
start that creates over a hundred of them, and a text that only repeats the fields. A
docstring that says what the record is costs nothing at import.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.support import REPO
from tests.test_imports import ROOMS

FOLDERS = (*(REPO / room for room in ROOMS), REPO / "motorctl" / "schema")


def is_dataclass(node: ast.ClassDef) -> bool:
    for decorator in node.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name == "dataclass":
            return True
    return False


def undocumented(path: Path, root: Path = REPO) -> list[str]:
    """The dataclasses of ``path`` without a docstring, as ``file:line Name``."""
    tree = ast.parse(path.read_text(), str(path))
    return [
        f"{path.relative_to(root)}:{node.lineno} {node.name}"
        for node in ast.walk(tree)
        if isinstance(node, ast.ClassDef) and is_dataclass(node) and not ast.get_docstring(node)
    ]


def test_every_dataclass_has_a_docstring() -> None:
    paths = [path for folder in FOLDERS for path in sorted(folder.rglob("*.py"))]
    assert len(paths) > 100  # the whole package, read as meant
    assert [d for path in paths for d in undocumented(path)] == []


def test_a_dataclass_without_one_is_named(tmp_path: Path) -> None:
    path = tmp_path / "records.py"
    path.write_text(
        "import dataclasses\nfrom dataclasses import dataclass\n\n"
        "@dataclass(frozen=True)\nclass A:\n    x: int\n\n"
        "@dataclasses.dataclass\nclass B:\n    'B.'\n    y: int\n\n"
        "@dataclass\nclass C:\n    z: int\n\n"
        "class D:\n    w: int\n"
    )
    assert undocumented(path, tmp_path) == ["records.py:5 A", "records.py:14 C"]
