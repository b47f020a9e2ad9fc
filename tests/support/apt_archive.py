"""A Debian archive as apt sees it, from recorded `apt-cache madison` output: stand-ins for
the `apt-cache` and `apt-get` commands, put first on a test's PATH (the tools' own command
line is the API faked; hwtest/vm/kernel_tuple.py and hwtest/run call them as they are).

`apt-cache depends linux-image-amd64` names the ABI in ``depends`` (the meta package's
dependency), `apt-cache pkgnames PREFIX` the package names of the recorded lines that begin
with PREFIX, `apt-cache madison NAME...` each name's recorded lines; `apt-get update`,
`install` and `download` are written to ``calls`` and do nothing else (update fails when
``update-fails`` exists). Edit ``madison`` (or
:meth:`FakeArchive.record`) to move the archive on between two runs. Each test owns its
archive's folder; nothing is shared.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tests.support import REPO

RECORDED = REPO / "tests" / "packaging" / "madison"
#: what this machine's archive held on 2026-11-28 (Debian 12 and its security archive): the
#: image, headers and headers-common of 6.1.0-56 at 6.1.192-2 only, linux-kbuild-6.1 at
#: 6.1.192-3 and 6.1.176-1 (the point release) only
TODAY = (RECORDED / "bookworm-2026-11-28.txt").read_text()

APT_CACHE = """#!/bin/sh
d='{folder}'
case $1 in
  depends) echo "$2"; [ -s "$d/depends" ] && echo "  Depends: linux-image-$(cat "$d/depends")";;
  pkgnames) awk -F'|' -v p="$2" '{{ n = $1; gsub(/ /, "", n) }} index(n, p) == 1 {{ print n }}' \\
    "$d/madison" | sort -u;;
  madison) shift; for p in "$@"; do
      awk -F'|' -v p="$p" '{{ n = $1; gsub(/ /, "", n) }} n == p' "$d/madison"; done;;
  *) echo "E: the stand-in apt-cache does not do $1" >&2; exit 100;;
esac
"""
APT_GET = """#!/bin/sh
d='{folder}'
echo "apt-get $*" >> "$d/calls"
case " $* " in
  *" update "*) [ ! -e "$d/update-fails" ] || {{
    echo "E: Failed to fetch http://deb.debian.org/ (stand-in)" >&2; exit 100; }};;
  *" install "*|*" download "*) ;;  # recorded only: nothing is installed or fetched
  *) echo "E: the stand-in apt-get does not do $*" >&2; exit 100;;
esac
"""


@dataclass
class FakeArchive:
    """The stand-ins in ``bin`` (put it first on PATH); their state in ``folder``."""

    folder: Path

    @property
    def bin(self) -> Path:
        return self.folder / "bin"

    def record(self, madison: str, depends: str = "6.1.0-56-amd64") -> None:
        (self.folder / "madison").write_text(madison)
        (self.folder / "depends").write_text(depends)

    def calls(self) -> list[str]:
        calls = self.folder / "calls"
        return calls.read_text().splitlines() if calls.exists() else []


def fake_archive(folder: Path, madison: str = TODAY) -> FakeArchive:
    """Stand-in apt-cache and apt-get in ``folder``/bin answering from ``madison``."""
    archive = FakeArchive(folder)
    archive.bin.mkdir(parents=True)
    for name, text in (("apt-cache", APT_CACHE), ("apt-get", APT_GET)):
        tool = archive.bin / name
        tool.write_text(text.format(folder=folder))
        tool.chmod(0o755)
    archive.record(madison)
    return archive


def without(madison: str, name: str, upstream: str = "") -> str:
    """The recorded lines less those of package ``name`` (at versions of ``upstream``,
    e.g. 6.1.192, when given)."""
    kept = []
    for line in madison.splitlines(keepends=True):
        fields = [f.strip() for f in line.split("|")]
        if fields[0] == name and (not upstream or fields[1].startswith(f"{upstream}-")):
            continue
        kept.append(line)
    return "".join(kept)


def replace_version(madison: str, name: str, old: str, new: str) -> str:
    """The recorded lines with package ``name`` at ``new`` where it was at ``old``."""
    out = []
    for line in madison.splitlines(keepends=True):
        fields = line.split("|")
        if fields[0].strip() == name and fields[1].strip() == old:
            line = "|".join([fields[0], fields[1].replace(old, new), *fields[2:]])
        out.append(line)
    return "".join(out)
