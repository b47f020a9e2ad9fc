"""The package's documents on an installed system (make test-deb runs it inside the test root).

Usage: check_docs.py [--root DIR] --source DIR --unit PATH... -- DOC...

- every DOC (a path in the repository: README.md, docs/..., docs/examples/...) is installed
  as /usr/share/doc/motorctl/DOC, uncompressed, with the bytes of the repository's copy
  (--source holds the repository's copies, at the same relative paths);
- every relative link in an installed Markdown document leads to a file that is installed
  (so docs/raspberry-pi.md's links work on the board);
- every ``Documentation=`` target of every unit PATH opens: ``file://`` the file, read;
  ``man:NAME(SECTION)`` the manual page, /usr/share/man/manSECTION/NAME.SECTION[.gz], read and
  holding a title line. Any other scheme cannot be opened on a board without network, and
  fails.

--root (default /): where the installed system is (tests/packaging/test_deb_docs.py checks
this checker on made-up roots). Prints one line per document, link and target; exit status 1
with every problem listed when anything is missing, 0 otherwise. Python's standard library
only (it runs on the root's python3).
"""

from __future__ import annotations

import gzip
import re
import sys
from pathlib import Path

DOC_DIR = "usr/share/doc/motorctl"
#: a Markdown link's target (inline form): [text](target) or [text](target "title")
LINK = re.compile(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
MAN = re.compile(r"^man:([A-Za-z0-9_.@+-]+)\(([0-9][a-z]*)\)$")


def installed_docs(root: Path, source: Path, docs: list[str]) -> list[str]:
    problems = []
    for doc in docs:
        path = root / DOC_DIR / doc
        if not path.is_file():
            gz = path.with_name(path.name + ".gz")
            why = f"compressed to {gz.name}" if gz.exists() else "not installed"
            problems.append(f"{doc}: {why} (want /{DOC_DIR}/{doc})")
        elif path.read_bytes() != (source / doc).read_bytes():
            problems.append(f"/{DOC_DIR}/{doc} differs from the repository's {doc}")
        else:
            print(f"doc: /{DOC_DIR}/{doc}")
    return problems


def links(root: Path) -> list[str]:
    problems = []
    base = root / DOC_DIR
    for page in sorted(base.rglob("*.md")):
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                continue  # another site, or a place in the same page
            where = (page.parent / target.split("#")[0]).resolve()
            name = f"/{page.relative_to(root)} -> {target}"
            if where.is_file() and where.is_relative_to(base.resolve()):
                print(f"link: {name}")
            else:
                problems.append(f"{name}: no such file in /{DOC_DIR}")
    return problems


def documentation(root: Path, unit: Path) -> list[str]:
    """Every Documentation= target of ``unit`` (a path under ``root``), opened."""
    problems = []
    targets = []
    for line in (root / unit).read_text().splitlines():
        if line.startswith("Documentation="):
            targets += line.removeprefix("Documentation=").split()
    if not targets:
        problems.append(f"{unit.name}: no Documentation=")
    for target in targets:
        why = _opens(root, target)
        if why is None:
            print(f"{unit.name}: Documentation={target}: opens")
        else:
            problems.append(f"{unit.name}: Documentation={target}: {why}")
    return problems


def _opens(root: Path, target: str) -> str | None:
    """None when ``target`` opens on the installed system, else why not."""
    if target.startswith("file://"):
        path = root / target.removeprefix("file://").lstrip("/")
        if not path.is_file():
            gz = path.with_name(path.name + ".gz")
            return f"{gz.name} is installed in its place" if gz.exists() else "no such file"
        path.read_bytes()
        return None
    man = MAN.match(target)
    if man is not None:
        name, section = man.groups()
        folder = root / "usr/share/man" / f"man{section[0]}"
        for page in (folder / f"{name}.{section}.gz", folder / f"{name}.{section}"):
            if page.is_file():
                text = gzip.decompress(page.read_bytes()) if page.suffix == ".gz" else None
                text = text if text is not None else page.read_bytes()
                return None if b".TH " in text else f"{page.name} has no .TH title line"
        return f"no manual page {name}({section}) in /usr/share/man/man{section[0]}"
    return "not a file: or man: target: it cannot be opened without network"


def main(argv: list[str]) -> int:
    root, source, units = Path("/"), Path("."), []
    args = list(argv)
    while args and args[0] != "--":
        flag, value = args.pop(0), args.pop(0)
        if flag == "--root":
            root = Path(value)
        elif flag == "--source":
            source = Path(value)
        elif flag == "--unit":
            units.append(Path(value.lstrip("/")))
        else:
            raise SystemExit(f"check_docs.py: unknown option {flag}")
    docs = args[1:]
    problems = installed_docs(root, source, docs) + links(root)
    for unit in units:
        problems += documentation(root, unit)
    if not docs or not units:
        problems.append("nothing to check: give the documents and the units")
    for problem in problems:
        print(f"PROBLEM: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
