"""Every repository path that README.md and docs/*.md name exists.

Read from each page: paths in prose, code spans, tables and command blocks that start with
one of the repository's top-level folders (``motion/profile.py``, ``docs/timing.md``,
``bench/steps.py``, ``tests/daemon/link/test_loop.py::test_name``); relative Markdown links
(``[status.md](status.md)``, from the page's own folder); and the README's architecture
map, whose file names are relative to the room their line group starts with (``motion/``
... ``engine.py``), or to a folder named earlier in that group (``config/ (model.py``).

The sources of the rooms split into wings so far (``SOURCE_ROOMS``: their docstrings and
comments, Python and C) are read the same way, and their file names in code spans (a
docstring's ``process/child.py``; any name in a C comment) must exist beside the file, in
``motion/executors/`` or at the root.

Not paths of this repository, so not checked: absolute paths (``/etc``, ``/dev``, ``/run``,
``/usr/bin/python3``), URLs, names with a placeholder (``motorctl_<version>-1_all.deb``),
and what the build and the runs make (``build/``, ``.venv/``, ``.run/``): none of those
starts with a tracked top-level folder.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.support import REPO

#: The repository's tracked top-level folders and files a page may name.
TOP_DIRS = (
    "client",
    "protocol",
    "daemon",
    "motion",
    "hal",
    "motorctl",
    "tests",
    "bench",
    "docs",
    "hwtest",
    "tools",
    "systemd",
    "debian",
    ".ci",
)
TOP_FILES = ("README.md", "Makefile", "pyproject.toml", "LICENSE")

PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
#: rooms whose sources are checked too (issue 23's wings; a room joins once its own are done)
SOURCE_ROOMS = ("motion",)
#: where a source's relative file names may be, besides its own folder
SOURCE_BASES = (REPO / "motion" / "executors", REPO)

#: A path that starts with a top-level folder, not inside another path, URL or word.
_PATH = re.compile(
    r"(?<![\w./@~-])(?:" + "|".join(re.escape(d) for d in TOP_DIRS) + r")/[\w.@*/<>{}+-]*"
)
_TOP_FILE = re.compile(r"(?<![\w./-])(?:" + "|".join(map(re.escape, TOP_FILES)) + r")(?![\w.-])")
#: [text](target): a link; the target is checked when it is not a URL or an anchor.
_LINK = re.compile(r"\]\(([^)\s]+)\)")
#: a line that starts a group of the README's map: "room/   what is in it"
_MAP_GROUP = re.compile(r"^([\w.-]+)/ {2,}")
#: a file or folder name inside a map group
_MAP_NAME = re.compile(r"(?<![\w./@-])([\w@-]+(?:\.[\w]+)+|[\w-]+/)(?![\w/])")


def _exists(path: str, base: Path = REPO) -> bool:
    if any(c in path for c in "<>{}"):
        return True  # a placeholder, not a name
    if "*" in path:
        return any(base.glob(path))
    return (base / path).exists()


def _clean(token: str) -> str:
    """The path in ``token``: no test id, no trailing punctuation of the prose."""
    return token.split("::", 1)[0].rstrip(".,;:)")


def named_paths(text: str) -> list[str]:
    """The repository paths ``text`` names (outside the README's map: see ``map_paths``)."""
    found = [_clean(m.group(0)) for m in _PATH.finditer(text)]
    found += _TOP_FILE.findall(text)
    return [p for p in found if p]


def link_targets(text: str) -> list[str]:
    """Relative link targets of ``text`` (no URLs, no in-page anchors)."""
    out = []
    for target in _LINK.findall(text):
        target = target.split("#", 1)[0]
        if target and not re.match(r"^[a-z][a-z0-9+.-]*:", target):
            out.append(target)
    return out


def map_block(readme: str) -> str:
    """The README's architecture map: the fenced block of the Architecture section whose
    lines start groups with ``room/``."""
    section = readme.split("\n## Architecture", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"^```[^\n]*\n(.*?)^```", section, re.M | re.S)
    maps = [b for b in blocks if sum(bool(_MAP_GROUP.match(line)) for line in b.splitlines()) > 2]
    assert len(maps) == 1, f"the Architecture section has {len(maps)} maps, not 1"
    return str(maps[0])


def map_paths(block: str) -> list[tuple[str, list[str]]]:
    """(name, where it may be) for every file and folder name of the map: in its room, in
    a folder its group names (before or after it; a folder nests in one named before it, as
    ``backends/`` then ``mock/``), or at the root."""
    groups: list[tuple[str, list[str]]] = []  # (room, names) per group
    for line in block.splitlines():
        group = _MAP_GROUP.match(line)
        if group:
            groups.append((group.group(1), []))
            line = line[group.end() :]
        if groups:
            groups[-1][1].extend(n for n in _MAP_NAME.findall(line) if "/" not in n.rstrip("/"))
    out: list[tuple[str, list[str]]] = []
    for room, names in groups:
        out.append((room + "/", [""]))
        folders = [room]
        for name in names:
            if name.endswith("/"):
                folders += [
                    f"{f}/{name.rstrip('/')}" for f in list(folders) if _exists(f"{f}/{name}")
                ]
        out += [(name, [*folders, ""]) for name in names]
    return out


#: a file name in a docstring's code span; in C, any file name (``#include`` lines aside)
_SPAN_NAME = re.compile(r"``([\w./-]+\.(?:py|c|h))``")
_C_NAME = re.compile(r"(?<![\w./-])((?:[\w-]+/)*[\w-]+\.(?:py|c|h))(?![\w/])")


def source_names(path: Path, text: str) -> list[str]:
    """The relative file names a source names (see the module's doc)."""
    if path.suffix == ".py":
        return _SPAN_NAME.findall(text)
    prose = "\n".join(ln for ln in text.splitlines() if not ln.lstrip().startswith("#include"))
    return _C_NAME.findall(prose)


def sources() -> list[Path]:
    return sorted(
        p
        for room in SOURCE_ROOMS
        for ext in ("py", "c", "h")
        for p in (REPO / room).rglob(f"*.{ext}")
    )


def _where(page: Path) -> str:
    return str(page.relative_to(REPO))


@pytest.mark.parametrize("page", PAGES, ids=_where)
def test_every_path_a_page_names_exists(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    if page.name == "README.md":
        text = text.replace(map_block(text), "")  # read by the map's own test
    missing = sorted({p for p in named_paths(text) if not _exists(p)})
    missing += sorted({t for t in link_targets(text) if not _exists(t, page.parent)})
    assert not missing, f"{_where(page)} names paths that do not exist: {missing}"


@pytest.mark.parametrize("path", sources(), ids=_where)
def test_every_path_a_source_names_exists(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    missing = sorted({p for p in named_paths(text) if not _exists(p)})
    missing += sorted(
        {
            name
            for name in source_names(path, text)
            if not any((base / name).exists() for base in (path.parent, *SOURCE_BASES))
        }
    )
    assert not missing, f"{_where(path)} names paths that do not exist: {missing}"


def test_every_name_in_the_readmes_map_exists() -> None:
    block = map_block((REPO / "README.md").read_text(encoding="utf-8"))
    entries = map_paths(block)
    assert len(entries) > 40, entries  # the map was read, not skipped
    missing = [
        name
        for name, folders in entries
        if not any(_exists(f"{f}/{name}" if f else name) for f in folders)
    ]
    assert not missing, f"README.md's architecture map names files that do not exist: {missing}"


@pytest.mark.parametrize(
    ("text", "paths"),
    [
        ("see `motion/profile.py` and docs/timing.md.", ["motion/profile.py", "docs/timing.md"]),
        (
            "| tests/daemon/link/test_loop.py::test_serves_and_stops |",
            ["tests/daemon/link/test_loop.py"],
        ),
        ("`bench/latency.py --trace` (bench/steps.py)", ["bench/latency.py", "bench/steps.py"]),
        ("/etc/motorctl.toml, /dev/spidev0.0, /run/motorctl/x, /usr/bin/python3", []),
        ("https://example.org/motion/profile.py and build/deb/build.log", []),
        ("a `.venv/bin/python`, `state.json`, motorctl.pty", []),
        ("the `Makefile`, pyproject.toml's settings", ["Makefile", "pyproject.toml"]),
    ],
    ids=[
        "prose and spans",
        "a test id",
        "a command",
        "absolute",
        "url and build output",
        "not in the repository",
        "top-level files",
    ],
)
def test_path_extraction(text: str, paths: list[str]) -> None:
    assert named_paths(text) == paths


def test_a_sources_file_names_are_read() -> None:
    py = REPO / "motion" / "executors" / "thread.py"
    assert source_names(py, "a ``process/child.py`` and ``ticks`` in ``gone.py``") == [
        "process/child.py",
        "gone.py",
    ]
    c = REPO / "motion" / "executors" / "csrc" / "core.c"
    assert source_names(c, "#include <poll.h>\n/* core.c mirrors step_core.py */") == [
        "core.c",
        "step_core.py",
    ]


def test_a_missing_path_is_caught() -> None:
    assert not _exists("motion/stepthread.py")
    assert not _exists("tests/test_nothing*.py")
    assert _exists("tests/hal/layers/tmc/test_*.py") and _exists("motorctl_<version>-1_all.deb")
    block = "motion/   engine.py, stepthread.py\ndaemon/   config/ (model.py), gone/\n"
    entries = dict(map_paths(block))
    assert entries["model.py"] == ["daemon", "daemon/config", ""]
    missing = [
        n for n, fs in map_paths(block) if not any(_exists(f"{f}/{n}" if f else n) for f in fs)
    ]
    assert missing == ["stepthread.py", "gone/"]
