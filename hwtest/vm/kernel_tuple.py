"""Which Debian kernel packages the gpio-sim VM is built from: the kernel tuple.

build.sh needs five packages that belong together: the image (vmlinuz and the modules),
its headers and the headers' -common part (the three are one ABI, built from one source
upload: always at one identical version), linux-kbuild (modpost, fixdep: the tools that
build out-of-tree modules) and linux-source (gpio-sim.c, irq_sim.c, spi-gpio.c, built out
of tree against those headers). Debian's security archive moves on unevenly: an upload may
rebuild linux-kbuild and linux-source (6.1.192-3) and not the image (6.1.192-2), and keeps
only the newest upload of each. So the tuple is chosen from what the archive holds now:

- image, headers and headers-common at one identical version; kbuild and source at the
  newest version of the same upstream version as the image (they may differ from it by
  the Debian revision only: the same kernel);
- the newest such complete tuple of the current ABI (what linux-image-amd64 depends on);
- if that ABI has none, the newest complete tuple of an older version in the same series
  (another linux-image-6.1.0-NN-amd64, e.g. the point release's): the VM then boots that
  ABI's image, the one the modules are built against, and a note on stderr says why;
- an ABI given with --kver (GSIM_KVER) is taken or refused, never replaced;
- nothing fits: one line naming what is missing, exit status 1.

Printed on stdout, one package a line as `name=version` (apt-get download's arguments, in
the order image, headers, headers-common, kbuild, source): build.sh downloads exactly
those and records them in the VM's KERNEL file; hwtest/run compares that record with what
the archive offers now and rebuilds a VM built for another tuple.

Run with the host's Python (/usr/bin/python3 -I): the standard library only, no venv.
Reads the archive through `apt-cache` (the lists as `apt-get update` last left them).
Everything here belongs to the one process that runs it; there is no shared state.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from dataclasses import dataclass

FLAVOUR = "amd64"
#: the ABIs this recipe knows how to name the packages of: 6.1.0-56 (Debian 12's 6.1
#: series: linux-kbuild-6.1, linux-source-6.1)
ABI_FORM = re.compile(r"(?P<series>\d+\.\d+)\.\d+-\d+")


class NoTuple(Exception):
    """No complete tuple (or an ABI this recipe cannot name); the message says what lacks."""


# --- Debian version order (dpkg's, deb-version(7)) ---------------------------------------


def _order(c: str) -> int:
    if c == "":
        return 0
    if c == "~":
        return -1
    if c.isalpha():
        return ord(c)
    return ord(c) + 256


def _compare_part(a: str, b: str) -> int:
    """dpkg's verrevcmp: non-digit runs by _order, digit runs as numbers."""
    i = j = 0
    while i < len(a) or j < len(b):
        while (i < len(a) and not a[i].isdigit()) or (j < len(b) and not b[j].isdigit()):
            ac = _order(a[i] if i < len(a) and not a[i].isdigit() else "")
            bc = _order(b[j] if j < len(b) and not b[j].isdigit() else "")
            if ac != bc:
                return -1 if ac < bc else 1
            i += 1
            j += 1
        start_i, start_j = i, j
        while i < len(a) and a[i].isdigit():
            i += 1
        while j < len(b) and b[j].isdigit():
            j += 1
        na, nb = int(a[start_i:i] or "0"), int(b[start_j:j] or "0")
        if na != nb:
            return -1 if na < nb else 1
    return 0


def _split(version: str) -> tuple[int, str, str]:
    epoch, _, rest = version.partition(":") if ":" in version else ("0", "", version)
    upstream, dash, revision = rest.rpartition("-")
    if not dash:
        upstream, revision = rest, ""
    return int(epoch or "0"), upstream, revision


def compare_versions(a: str, b: str) -> int:
    """-1, 0 or 1 as Debian orders versions a and b (`dpkg --compare-versions`)."""
    ea, ua, ra = _split(a)
    eb, ub, rb = _split(b)
    if ea != eb:
        return -1 if ea < eb else 1
    return _compare_part(ua, ub) or _compare_part(ra, rb)


def upstream_of(version: str) -> str:
    """The version without its Debian revision (the epoch kept): 6.1.192-2 -> 6.1.192."""
    epoch, upstream, _ = _split(version)
    return f"{epoch}:{upstream}" if epoch else upstream


class _Key:
    """A version as a sort key in Debian's order."""

    def __init__(self, version: str) -> None:
        self.version = version

    def __lt__(self, other: _Key) -> bool:
        return compare_versions(self.version, other.version) < 0

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Key) and compare_versions(self.version, other.version) == 0

    __hash__ = None  # type: ignore[assignment]


# --- the archive as apt-cache madison shows it -------------------------------------------


def parse_madison(text: str) -> dict[str, list[str]]:
    """Each binary package's versions in the archive, newest first, each once.

    A line is `name | version | uri suite/component arch Packages`; source lines (Sources)
    and anything else are left out."""
    found: dict[str, set[str]] = {}
    for line in text.splitlines():
        fields = [field.strip() for field in line.split("|")]
        if len(fields) != 3 or not fields[2].endswith("Packages"):
            continue
        found.setdefault(fields[0], set()).add(fields[1])
    return {name: sorted(vs, key=_Key, reverse=True) for name, vs in found.items()}


@dataclass(frozen=True)
class Names:
    """The five packages of one ABI."""

    abi: str

    @property
    def series(self) -> str:
        match = ABI_FORM.fullmatch(self.abi)
        if match is None:
            raise NoTuple(
                f"kernel ABI {self.abi!r} is not of the form X.Y.Z-N this recipe knows "
                "(linux-kbuild-X.Y, linux-source-X.Y; Debian 12's 6.1 series)"
            )
        return match["series"]

    @property
    def image(self) -> str:
        return f"linux-image-{self.abi}-{FLAVOUR}"

    @property
    def headers(self) -> str:
        return f"linux-headers-{self.abi}-{FLAVOUR}"

    @property
    def common(self) -> str:
        return f"linux-headers-{self.abi}-common"

    @property
    def kbuild(self) -> str:
        return f"linux-kbuild-{self.series}"

    @property
    def source(self) -> str:
        return f"linux-source-{self.series}"


@dataclass(frozen=True)
class KernelTuple:
    abi: str
    version: str  # the image's, the headers' and headers-common's
    kbuild: str
    source: str

    @property
    def kver(self) -> str:
        return f"{self.abi}-{FLAVOUR}"

    def packages(self) -> list[tuple[str, str]]:
        n = Names(self.abi)
        return [
            (n.image, self.version),
            (n.headers, self.version),
            (n.common, self.version),
            (n.kbuild, self.kbuild),
            (n.source, self.source),
        ]

    def lines(self) -> list[str]:
        return [f"{name}={version}" for name, version in self.packages()]


@dataclass(frozen=True)
class Choice:
    chosen: KernelTuple
    note: str  # why not the current ABI's newest image, or ""


def _has(archive: dict[str, list[str]], name: str) -> str:
    versions = archive.get(name)
    return f"the archive has {', '.join(versions)}" if versions else "not in the archive"


def _tuple_at(
    archive: dict[str, list[str]], abi: str, version: str
) -> tuple[KernelTuple | None, list[str]]:
    """The complete tuple of image ABI at version, or None and what it lacks."""
    n = Names(abi)
    missing = [
        f"{name} {version} ({_has(archive, name)})"
        for name in (n.headers, n.common)
        if version not in archive.get(name, [])
    ]
    up = upstream_of(version)
    same: dict[str, str] = {}
    for name in (n.kbuild, n.source):
        match = [v for v in archive.get(name, []) if upstream_of(v) == up]
        if match:
            same[name] = match[0]  # newest first
        else:
            missing.append(f"{name} {up}-* ({_has(archive, name)})")
    if missing:
        return None, missing
    return KernelTuple(abi, version, same[n.kbuild], same[n.source]), []


def _abis(archive: dict[str, list[str]], series: str) -> list[str]:
    image = re.compile(rf"linux-image-(?P<abi>.+)-{FLAVOUR}")
    found = []
    for name in archive:
        match = image.fullmatch(name)
        if match is None:
            continue
        form = ABI_FORM.fullmatch(match["abi"])
        if form is not None and form["series"] == series:
            found.append(match["abi"])
    return found


def choose(archive: dict[str, list[str]], abi: str, fallback: bool) -> Choice:
    """The newest complete tuple of ABI; with fallback, else the newest complete one of an
    older version in its series. NoTuple names what the current ABI's newest image lacks."""
    names = Names(abi)
    series = names.series
    current = archive.get(names.image, [])
    if not current and not fallback:
        raise NoTuple(f"{names.image}: not in the archive")
    candidates = [(v, abi) for v in current]
    if fallback:
        newest = current[0] if current else None
        candidates += [
            (v, other)
            for other in _abis(archive, series)
            if other != abi
            for v in archive[Names(other).image]
            if newest is None or compare_versions(v, newest) < 0
        ]
    # newest first; at one version, the current ABI before any other
    candidates.sort(key=lambda c: (_Key(c[0]), c[1] == abi), reverse=True)
    first_missing: list[str] = []
    older_missing = ""
    for version, which in candidates:
        found, missing = _tuple_at(archive, which, version)
        if found is not None:
            note = ""
            if (version, which) != (current[0] if current else None, abi):
                lacks = (
                    f"{names.image} {current[0]} lacks {'; '.join(first_missing)}"
                    if current
                    else f"{names.image} is not in the archive"
                )
                note = f"{lacks}: taking the newest complete tuple of an older version"
            return Choice(found, note)
        if which == abi and not first_missing:
            first_missing = missing
        elif which != abi and not older_missing:
            older_missing = f"{Names(which).image} {version}, lacks {'; '.join(missing)}"
    head = (
        f"{names.image} {current[0]} lacks {'; '.join(first_missing)}"
        if current
        else f"{names.image}: not in the archive"
    )
    if not fallback:
        raise NoTuple(f"no complete kernel tuple: {head} (GSIM_KVER={names.abi}-{FLAVOUR})")
    older = (
        f"nor is any older one: the newest, {older_missing}"
        if older_missing
        else f"and there is no older linux-image-{series}.*-{FLAVOUR} in the archive"
    )
    raise NoTuple(f"no complete kernel tuple: {head}; {older}")


# --- the archive through apt-cache --------------------------------------------------------


def _apt_cache(*args: str) -> str:
    env = dict(os.environ, LC_ALL="C")
    try:
        done = subprocess.run(
            ["apt-cache", *args], capture_output=True, text=True, env=env, check=False
        )
    except FileNotFoundError:
        raise NoTuple("apt-cache not found: the VM is built from Debian's packages") from None
    if done.returncode != 0:
        err = done.stderr.strip().splitlines()
        raise NoTuple(f"apt-cache {args[0]} failed: {err[-1] if err else done.returncode}")
    return done.stdout


def current_kver() -> str:
    """What linux-image-amd64 depends on: 6.1.0-56-amd64."""
    meta = f"linux-image-{FLAVOUR}"
    for line in _apt_cache("depends", meta).splitlines():
        kind, _, dep = line.strip().partition(" ")
        if kind == "Depends:" and re.fullmatch(rf"linux-image-\S+-{FLAVOUR}", dep):
            return dep.removeprefix("linux-image-")
    raise NoTuple(f"{meta} depends on no linux-image-*-{FLAVOUR} (apt-get update?)")


def read_archive(abi: str) -> dict[str, list[str]]:
    """apt-cache madison for the five packages of ABI and of every other ABI of its series."""
    series = Names(abi).series
    images = re.compile(rf"linux-image-{re.escape(series)}\.\d+-\d+-{FLAVOUR}")
    abis = {abi} | {
        name.removeprefix("linux-image-").removesuffix(f"-{FLAVOUR}")
        for name in _apt_cache("pkgnames", "linux-image-").split()
        if images.fullmatch(name)
    }
    wanted = [Names(a).image for a in sorted(abis)]
    wanted += [name for a in sorted(abis) for name in (Names(a).headers, Names(a).common)]
    wanted += [Names(abi).kbuild, Names(abi).source]
    return parse_madison(_apt_cache("madison", *wanted))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="kernel_tuple.py",
        description="Print the kernel packages (name=version) the gpio-sim VM is built from.",
    )
    parser.add_argument(
        "--kver",
        default="",
        help="this ABI and no other (e.g. 6.1.0-56-amd64; build.sh's GSIM_KVER); "
        "default: what linux-image-amd64 depends on, or an older one when it is incomplete",
    )
    args = parser.parse_args(argv)
    try:
        kver = args.kver or current_kver()
        if not kver.endswith(f"-{FLAVOUR}"):
            raise NoTuple(f"--kver {kver!r}: not an {FLAVOUR} kernel (e.g. 6.1.0-56-{FLAVOUR})")
        abi = kver.removesuffix(f"-{FLAVOUR}")
        choice = choose(read_archive(abi), abi, fallback=not args.kver)
    except NoTuple as e:
        print(f"kernel_tuple: {e}", file=sys.stderr)
        return 1
    if choice.note:
        print(f"kernel_tuple: {choice.note}", file=sys.stderr)
    print("\n".join(choice.chosen.lines()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
