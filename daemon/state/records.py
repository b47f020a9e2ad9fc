"""The state files' format and their strict reading: what a saved motor is, what is trusted.

Where: ``state.json`` and the motion journal ``state.moving`` live in one directory, by
default the runtime directory /run/motorctl (a tmpfs: state survives a daemon restart and
is gone after a reboot, like a microcontroller's RAM); ``[state] directory`` in the config
moves them, e.g. to /var/lib/motorctl (docs/service.md says when that is wise).

What is trusted: a state file is read strictly, record by record. Whatever stands at
``state.json`` that is not a readable regular file (a directory, a symbolic link, a FIFO, a
file that cannot be read), a file larger than ``MAX_FILE_BYTES`` (refused unread), bad
bytes, JSON that Python's parser cannot take (bad syntax, nesting too deep, an integer of
thousands of digits) or a file without a list of motor records restores nothing: every
motor must be homed again. A motor record that is wrong in itself
(wrong types, a position outside the 24-bit range, more waypoints than any table holds, a
name that two records share) or written for another motor (its name, or the fingerprint
of its geometry, does not match the config) restores nothing for that motor only
(:func:`match_motors`); a record for a motor the config does not have restores nothing
either (:func:`unmatched_records`). What follows from that (the file set aside, the log)
is daemon/state/persistence.py's.

Pure but for :func:`read_regular` and :func:`read_state`, which read a file as the daemon
reads every file it wrote (daemon/state/files.py): no state of its own; called by whichever
thread reads or writes the state (the main thread at start, the state writer).
"""

from __future__ import annotations

import hashlib
import json
import os
import reprlib
import stat
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from motorctl.daemon.state.files import describe, folder_owner, ours
from motorctl.protocol.codec import POS_MAX, POS_MIN, WAYPOINTS

STATE_VERSION = 2
STATE_NAME = "state.json"
JOURNAL_NAME = "state.moving"
#: The largest state or journal file read: 64 motors with full tables write about 240 KiB
#: (tests/daemon/state/test_persistence.py checks it); anything larger is not this daemon's
#: and is set aside unread.
MAX_FILE_BYTES = 4 << 20

_show = reprlib.Repr()
_show.maxstring = _show.maxother = _show.maxlong = 40


class StateError(Exception):
    """The state file cannot be trusted; the message names the file and the problem."""


def geometry_fingerprint(fields: Mapping[str, object]) -> str:
    """A short, stable hash of what gives a motor's positions their meaning."""
    text = json.dumps(dict(fields), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class MotorIdentity:
    """What a saved motor must match to be restored: its config name and geometry."""

    name: str
    fingerprint: str
    max_waypoints: int = WAYPOINTS
    steps_per_rev: int = 0  # > 0: rotary, positions in [0, steps_per_rev)


@dataclass
class SavedMotor:
    """One motor's record in a state file: who it is (name and fingerprint), where it was,
    its home and waypoints, and whether it was moving or had lost its position."""

    name: str
    fingerprint: str
    position: int
    home: int
    waypoints: list[int]
    moving: bool
    position_lost: bool

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "fingerprint": self.fingerprint,
            "position": self.position,
            "home": self.home,
            "waypoints": list(self.waypoints),
            "moving": self.moving,
            "position_lost": self.position_lost,
        }


@dataclass(frozen=True)
class BadRecord:
    """A motor record of a state file that cannot be trusted: where, whose, and why."""

    index: int  # its place in the file's list of motors
    name: str | None  # None when the record has no usable name
    problem: str


@dataclass
class SavedState:
    """A state file as read: its good motor records, what else it held, the bad records."""

    motors: list[SavedMotor]  # the good records, in file order
    extra: dict[str, Any] = field(default_factory=dict)  # e.g. the mock world's axes
    bad: list[BadRecord] = field(default_factory=list)  # the records that are not
    slots: dict[str, int] = field(default_factory=dict)  # name -> place in the file (read)

    def to_bytes(self) -> bytes:
        data: dict[str, Any] = {
            "version": STATE_VERSION,
            "motors": [m.to_json() for m in self.motors],
        }
        data.update(self.extra)
        return (json.dumps(data, indent=1, sort_keys=True) + "\n").encode()


# -- reading --------------------------------------------------------------------------------
def _int(value: object, where: str, lo: int = POS_MIN, hi: int = POS_MAX) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise StateError(f"{where} is {_show.repr(value)}, not an integer")
    if not lo <= value <= hi:
        raise StateError(f"{where} is {value}, outside {lo}..{hi}")
    return value


def _bool(value: object, where: str) -> bool:
    if not isinstance(value, bool):
        raise StateError(f"{where} is {_show.repr(value)}, not true or false")
    return value


def _str(value: object, where: str) -> str:
    if not isinstance(value, str):
        raise StateError(f"{where} is {_show.repr(value)}, not a string")
    return value


def parse_motor(m: object, where: str) -> SavedMotor:
    """One motor record; StateError says what is wrong with it."""
    if not isinstance(m, dict):
        raise StateError(f"{where} is not an object")
    wps = m.get("waypoints")
    if not isinstance(wps, list):
        raise StateError(f"{where}.waypoints is not a list")
    if len(wps) > WAYPOINTS:
        raise StateError(f"{where} has {len(wps)} waypoints, the table holds {WAYPOINTS}")
    return SavedMotor(
        name=_str(m.get("name"), f"{where}.name"),
        fingerprint=_str(m.get("fingerprint"), f"{where}.fingerprint"),
        position=_int(m.get("position"), f"{where}.position"),
        home=_int(m.get("home"), f"{where}.home"),
        waypoints=[_int(w, f"{where}.waypoints[{j}]") for j, w in enumerate(wps)],
        moving=_bool(m.get("moving"), f"{where}.moving"),
        position_lost=_bool(m.get("position_lost"), f"{where}.position_lost"),
    )


def parse_state(raw: bytes) -> SavedState:
    """Parse and check a state file's bytes (without a path in the messages).

    StateError when the file as a whole cannot be trusted; a motor record that cannot be
    is listed in :attr:`SavedState.bad` with its problem, and the other records stand.
    """
    data = _json_object(raw)
    good, bad = _records(_motor_list(data))
    twins = _same_names(good, bad)
    shared = {b.name for b in twins}
    bad = sorted(bad + twins, key=lambda b: b.index)
    kept = [(i, saved) for i, saved in good if saved.name not in shared]
    extra = {k: v for k, v in data.items() if k not in ("version", "motors")}
    return SavedState(
        [saved for _, saved in kept], extra, bad, {saved.name: i for i, saved in kept}
    )


def _json_object(raw: bytes) -> dict[str, Any]:
    """The file as a JSON object: UTF-8 text that Python's parser takes, an object."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise StateError(f"not UTF-8 text (byte {exc.start})") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StateError(f"not valid JSON ({exc})") from exc
    except RecursionError:
        raise StateError("JSON nested too deeply to be read") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        why = str(exc).split(":")[0]  # without the advice to raise Python's own limit
        raise StateError(f"JSON that cannot be read ({why})") from None
    if not isinstance(data, dict):
        raise StateError("not a JSON object")
    return data


def _motor_list(data: dict[str, Any]) -> list[object]:
    """The header's checks (the version this daemon writes), then the list of records."""
    if data.get("version") != STATE_VERSION:
        version = _show.repr(data.get("version"))
        raise StateError(f"version is {version}, this daemon writes {STATE_VERSION}")
    motors = data.get("motors")
    if not isinstance(motors, list):
        raise StateError("'motors' is missing or not a list")
    return motors


def _records(motors: list[object]) -> tuple[list[tuple[int, SavedMotor]], list[BadRecord]]:
    """Each record on its own: the good ones with their place in the file, and the bad
    ones with their problem (and their name, where it is a string)."""
    good: list[tuple[int, SavedMotor]] = []
    bad: list[BadRecord] = []
    for i, m in enumerate(motors):
        try:
            good.append((i, parse_motor(m, f"motors[{i}]")))
        except StateError as exc:
            name = m.get("name") if isinstance(m, dict) else None
            bad.append(BadRecord(i, name if isinstance(name, str) else None, str(exc)))
    return good, bad


def _same_names(good: list[tuple[int, SavedMotor]], bad: list[BadRecord]) -> list[BadRecord]:
    """The good records whose name another record (good or bad) has too, made bad: none of
    them can be told to be that motor's."""
    names = Counter([s.name for _, s in good] + [b.name for b in bad if b.name is not None])
    return [
        BadRecord(
            i, saved.name, f"{names[saved.name]} motor records are named {_show.repr(saved.name)}"
        )
        for i, saved in good
        if names[saved.name] > 1
    ]


def read_state(path: Path) -> SavedState | None:
    """The saved state, None when there is none; StateError when it cannot be trusted."""
    try:
        raw = read_regular(path)
    except FileNotFoundError:
        return None
    try:
        return parse_state(raw)
    except StateError as exc:
        raise StateError(f"{path}: {exc}") from exc


def read_regular(path: Path, limit: int = MAX_FILE_BYTES) -> bytes:
    """The bytes of the regular file at ``path`` that is the daemon's own (daemon/state/files.py:
    not another user's, not a hard link to a file elsewhere): never through a symbolic
    link, never opening a FIFO or a device, never more than ``limit`` bytes (a larger file
    is refused unread). FileNotFoundError when nothing is there; StateError naming what is
    there instead, or why it cannot be read."""
    owner = folder_owner(path)
    try:
        st = os.lstat(path)
        if not ours(st, owner):
            raise StateError(_not_ours(path, st, owner))
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise StateError(f"{path} cannot be read: {exc.strerror}") from exc
    try:
        st = os.fstat(fd)
        if not ours(st, owner):  # replaced since the lstat
            raise StateError(_not_ours(path, st, owner))
        if st.st_size > limit:
            raise StateError(_too_large(path, st.st_size, limit))
        chunks = []
        size = 0
        while size <= limit and (chunk := os.read(fd, min(1 << 16, limit + 1 - size))):
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:  # it grew while being read
            raise StateError(_too_large(path, size, limit))
        return b"".join(chunks)
    except OSError as exc:
        raise StateError(f"{path} cannot be read: {exc.strerror}") from exc
    finally:
        os.close(fd)


def _not_ours(path: Path, st: os.stat_result, owner: int) -> str:
    what = describe(st, owner)
    if stat.S_ISREG(st.st_mode):
        return f"{path} is {what}, not this daemon's"
    return f"{path} is {what}, not a regular file"


def _too_large(path: Path, size: int, limit: int) -> str:
    return (
        f"{path} has {size} bytes, more than the {limit >> 20} MiB of the largest file "
        "this daemon reads (not read)"
    )


@dataclass
class Match:
    """For one configured motor: what the state file had for it, or why nothing."""

    saved: SavedMotor | None
    problem: str | None = None


def match_motors(state: SavedState, motors: Sequence[MotorIdentity]) -> list[Match]:
    """Pair saved motors with configured ones by name; check geometry and table size."""
    by_name = {m.name: m for m in state.motors}
    bad_by_name = {b.name: b for b in state.bad if b.name is not None}
    out = []
    for ident in motors:
        saved = by_name.get(ident.name)
        bad = bad_by_name.get(ident.name)
        if bad is not None:
            out.append(Match(None, f"its record cannot be trusted: {bad.problem}"))
        elif saved is None:
            out.append(Match(None, "not in the state file"))
        elif saved.fingerprint != ident.fingerprint:
            out.append(Match(None, "its geometry changed since the state was written"))
        elif len(saved.waypoints) > ident.max_waypoints:
            out.append(
                Match(
                    None,
                    f"{len(saved.waypoints)} waypoints saved, its table "
                    f"holds {ident.max_waypoints}",
                )
            )
        elif ident.steps_per_rev > 0 and not 0 <= saved.position < ident.steps_per_rev:
            out.append(Match(None, f"position {saved.position} outside its revolution"))
        else:
            out.append(Match(saved))
    return out


def unmatched_records(state: SavedState, motors: Sequence[MotorIdentity]) -> list[str]:
    """The records of the file that belong to no configured motor, each described: motors
    the config does not have, and records without a usable name."""
    names = {ident.name for ident in motors}
    out = [
        (
            state.slots.get(saved.name, -1),
            f"motor {_show.repr(saved.name)}, which the config does not have",
        )
        for saved in state.motors
        if saved.name not in names
    ]
    out += [
        (b.index, f"motors[{b.index}] of no configured motor ({b.problem})")
        for b in state.bad
        if b.name not in names
    ]
    return [text for _, text in sorted(out)]
