"""Reading trace files for ``motorctl trace`` and ``motorctl replay`` alike: one reader, so
both accept the same files and name the same problems (docs/trace.md, "Reading files").

:func:`load` reads the files through :func:`motorctl.protocol.capture.parse` and makes
links of them: each USER0 interface its own (a mergecap of the tap's recording and the
daemon's trace holds two), its parts (rotated files given in any order, sections put
together with ``cat``) in time order, checked for a missing part, a session whose start is
missing and files that overlap in time. Every problem names its file (and the reader's
byte offset).

Runs on the caller's thread.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from motorctl.protocol.capture import (
    LINKTYPE_USER0,
    Capture,
    CaptureError,
    CaptureInfo,
    Interface,
    Record,
    linktype_name,
    parse,
)


class TraceFileError(Exception):
    """A file that cannot be read as a trace; the message names it and says why."""


@dataclass
class Link:
    """One recorded link: an interface's runs over every file and section given (rotated
    parts, files put together with ``cat``), in time order, with its settings (None: no
    motorctl header: the defaults) and where its runs came from (``sources``: (index of its
    first run, file) per file, for rows naming their file)."""

    interface: int
    name: str
    info: CaptureInfo | None
    records: list[Record] = field(default_factory=list)
    sessions: dict[str, list[int]] = field(default_factory=dict)  # session -> parts given
    sources: list[tuple[int, str]] = field(default_factory=list)

    def file_of(self, index: int) -> str:
        """The file run ``index`` came from."""
        name = ""
        for start, path in self.sources:
            if start > index:
                break
            name = path
        return name


@dataclass
class Recording:
    """What ``motorctl trace`` and ``motorctl replay`` read: the links of the files (each
    USER0 interface its own; ``--interface`` keeps one), every interface the files describe,
    and the problems found, each naming its file and offset."""

    files: list[Path]
    links: list[Link]
    interfaces: list[Interface]
    problems: list[str] = field(default_factory=list)
    formats: list[str] = field(default_factory=list)

    @property
    def records(self) -> list[Record]:
        """Every run of the links kept, in time order."""
        if len(self.links) == 1:
            return self.links[0].records
        return sorted((r for link in self.links for r in link.records), key=lambda r: r.ts_ns)

    @property
    def info(self) -> CaptureInfo | None:
        """The settings of the first link (None: none, or no motorctl header)."""
        return self.links[0].info if self.links else None

    def describe_interfaces(self) -> str:
        """The interfaces in words: "0: /dev/ttyS0 (daemon, 120 runs), 1: ... (tap, ...)"."""
        counts = {link.interface: len(link.records) for link in self.links}
        return ", ".join(_interface_text(i, counts.get(i.number)) for i in self.interfaces)


def _interface_text(iface: Interface, runs: int | None) -> str:
    what = [iface.info.role] if iface.info is not None else []
    if iface.link_type != LINKTYPE_USER0:
        what.append(f"{linktype_name(iface.link_type)}, not motorctl's")
        if iface.offset >= 0:
            what.append(f"described at offset {iface.offset}")
    elif runs is not None:
        what.append(f"{runs} runs")
    return f"{iface.number}: {iface.name or 'unnamed'}" + (f" ({', '.join(what)})" if what else "")


@dataclass
class _Unit:
    """One interface's runs within one section of one file."""

    path: Path
    iface: Interface
    records: list[Record]

    @property
    def info(self) -> CaptureInfo | None:
        return self.iface.info

    @property
    def span(self) -> tuple[int, int] | None:
        return (self.records[0].ts_ns, self.records[-1].ts_ns) if self.records else None


def read(path: Path, data: bytes | None = None) -> Capture:
    """One file (``data``: its bytes, already read), as :func:`load` reads each."""
    if data is None:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise TraceFileError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        cap = parse(data)
    except CaptureError as exc:
        raise TraceFileError(f"{path}: {exc}") from None
    if not cap.sections:
        raise TraceFileError(f"{path}: {'; '.join(cap.problems)}: nothing in it can be read")
    return cap


def _units(path: Path, cap: Capture) -> list[_Unit]:
    """The file's records, per section and interface (a section ends where the next starts)."""
    starts = [s.offset for s in cap.sections]
    by_key: dict[tuple[int, int], list[Record]] = {}
    for rec in cap.records:
        where = bisect.bisect_right(starts, rec.offset) - 1
        by_key.setdefault((max(where, 0), rec.interface), []).append(rec)
    units = []
    for index, section in enumerate(cap.sections):
        for iface in section.interfaces:
            if iface.link_type == LINKTYPE_USER0:
                units.append(_Unit(path, iface, by_key.get((index, iface.number), [])))
    return units


def load(paths: Sequence[Path], interface: int | None = None) -> Recording:
    """Read trace files: each USER0 interface is a link of its own (a mergecap of the tap's
    recording and the daemon's trace holds two); a link's parts (rotated files in any
    order, sections put together with ``cat``) are put in time order and checked: a part
    missing, a session whose start is missing, files that overlap in time (not parts of one
    recording: TraceFileError). ``interface``: keep that link only (TraceFileError when
    there is none of that number)."""
    return links_of([(path, read(path)) for path in paths], interface)


def links_of(files: Sequence[tuple[Path, Capture]], interface: int | None = None) -> Recording:
    """:func:`load`'s work on files already read (:func:`read`)."""
    paths = [path for path, _ in files]
    units: list[_Unit] = []
    problems: list[str] = []
    formats: list[str] = []
    described: dict[int, Interface] = {}
    ends = 0
    for path, cap in files:
        ends = cap.size
        formats.append(cap.format)
        problems += [f"{path}: {p}" for p in cap.problems]
        units += _units(path, cap)
        for iface in cap.interfaces:
            described.setdefault(iface.number, iface)
    interfaces = [described[n] for n in sorted(described)]
    if not interfaces:
        raise TraceFileError(
            f"{', '.join(map(str, paths))}: no interface is described"
            + (f" ({'; '.join(problems)})" if problems else f" before the end at offset {ends}")
            + ": nothing to read"
        )
    if not units:
        raise TraceFileError(
            f"{', '.join(map(str, paths))}: no motorctl link in "
            f"{'it' if len(paths) == 1 else 'them'} (LINKTYPE_USER0, 147): interfaces "
            + ", ".join(_interface_text(i, None) for i in interfaces)
        )
    numbers = sorted({u.iface.number for u in units})
    if interface is not None:
        if interface not in numbers:
            raise TraceFileError(
                f"no motorctl interface {interface} in {', '.join(map(str, paths))}: it holds "
                + ", ".join(_interface_text(i, None) for i in interfaces)
            )
        numbers = [interface]
    links = [_link([u for u in units if u.iface.number == n], problems) for n in numbers]
    return Recording(list(paths), links, interfaces, problems, formats)


def _link(units: list[_Unit], problems: list[str]) -> Link:
    """One interface's units as one link: ordered, checked, put together."""
    units = sorted(units, key=lambda u: (u.span or (0, 0))[0])
    first = next((u for u in units if u.info is not None), units[0])
    link = Link(first.iface.number, first.iface.name, first.info)
    kept: list[_Unit] = []
    seen: dict[tuple[str, int], _Unit] = {}
    for unit in units:
        info = unit.info
        if info is not None and info.session and info.part:
            key = (info.session, info.part)
            if key in seen:
                problems.append(
                    f"{unit.path}: part {info.part} of session {info.session} was given "
                    f"already ({seen[key].path}); left out"
                )
                continue
            seen[key] = unit
            link.sessions.setdefault(info.session, []).append(info.part)
        if link.info is not None and info is not None and info.settings() != link.info.settings():
            problems.append(f"{unit.path}: recorded with other settings ({info.comment()})")
        kept.append(unit)
    spans = [(u, u.span) for u in kept if u.span is not None]
    for (a, sa), (b, sb) in itertools.pairwise(spans):
        assert sa is not None and sb is not None
        if sb[0] < sa[1]:
            raise TraceFileError(
                f"{a.path} and {b.path} overlap in time (interface {link.interface}): they are "
                "not parts of one recording (rotated parts follow each other); read them one "
                "at a time, or merge them with mergecap and pick one with --interface N"
            )
    for session, parts in link.sessions.items():
        parts.sort()
        where = f"interface {link.interface}, " if link.interface else ""
        if parts[0] > 1:
            problems.append(
                f"the start of session {session} ({where}part 1) is missing: the first part "
                f"given is part {parts[0]}; parts before it were rotated away or not given, "
                "and answers at the start may answer frames of the missing part"
            )
        missing = sorted(set(range(parts[0], parts[-1] + 1)) - set(parts))
        if missing:
            problems.append(
                f"session {session} ({where}parts {parts[0]}..{parts[-1]}) lacks part"
                f"{'s' if len(missing) > 1 else ''} {', '.join(map(str, missing))}: the "
                "frames recorded there are not here, and frames and answers around the hole "
                "may pair wrongly"
            )
    for unit in kept:
        if unit.records:
            if not link.sources or link.sources[-1][1] != str(unit.path):
                link.sources.append((len(link.records), str(unit.path)))
            link.records += unit.records
    return link
