"""Persistence: home positions, waypoints and positions of motors at rest.

Over 500 lines on purpose: the state file's reader, its writers (the motion journal,
atomic writes, the writer thread) and :class:`Persistence` share one format and the trust
rules this docstring states once; they change together.

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
of its geometry, does not match the config) restores nothing for that motor only; a record
for a motor the config does not have restores nothing either. Whenever anything was not
restored, the file is set aside for inspection under the first free name of
``state.json.bad``, ``state.json.bad.1``, ``state.json.bad.2``, ... (never replacing an
older one), and the log names it.

How it is written: complete or absent. A temporary file is written in full (looping on
short writes), fsynced, renamed over the state file, and the directory is fsynced. The
temporary file and the motion journal are opened as every file the daemon writes
(daemon/paths.py: never through a link, never a FIFO or a device, never someone else's
file): whatever stands in their way (a directory, a symbolic link, ...) is set aside the
same way, so the daemon can always write while its directory is writable. A motion journal
that cannot be read is set aside once the state file written after it is durable.

Moving before the ACK: a motion command must not be acknowledged while the state on disk
still says its motor is at rest (a SIGKILL right then would restore a stale position).
:class:`MotionJournal` is a write-ahead record of one byte per motor, set and fdatasynced
before the motion starts; the writer clears it once a state file with the motor at rest
again is durable. A command that found its motor at rest on disk and left it there (a move
of no distance, a refused command) clears the byte itself before it is answered
(``withdraw``), since the state on disk is still right: only a motor that really moved may
come back lost. A motor whose byte is set when the daemon starts has lost its position.

Threads: :class:`StateWriter` writes on its own thread on request (motor events, which come
from the step thread and must not wait for a disk) and synchronously when asked by the link
thread (SaveHome/SaveWayPoint, answered only after the write). Its write lock serialises
both. :class:`MotionJournal` is called by the link thread (``begin``/``end``/``withdraw``)
and the writer thread (``clear_if_unchanged``) and guards itself with a lock; ``begin``
blocks on one ``fdatasync`` of a tiny file, and only when the motor was at rest on disk.
``Persistence`` takes the engine lock briefly before and after a motion from rest (where
was the motor, did it move).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
import reprlib
import stat
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from motorctl.daemon.paths import (
    clear_the_way,
    describe,
    folder_owner,
    open_for_writing,
    ours,
    set_aside,
)

if TYPE_CHECKING:
    from motorctl.motion.engine import MotionEngine as Engine

log = logging.getLogger("motorctl.state")

STATE_VERSION = 2
STATE_NAME = "state.json"
JOURNAL_NAME = "state.moving"
POS_MIN = -(1 << 23)
POS_MAX = (1 << 23) - 1
MAX_WAYPOINTS = 255  # the protocol's table size; a motor's configured table may be smaller
#: The largest state or journal file read: 64 motors with full tables write about 240 KiB
#: (tests/daemon/test_state.py checks it); anything larger is not this daemon's and is set
#: aside unread.
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
    max_waypoints: int = MAX_WAYPOINTS
    steps_per_rev: int = 0  # > 0: rotary, positions in [0, steps_per_rev)


@dataclass
class SavedMotor:
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
    if len(wps) > MAX_WAYPOINTS:
        raise StateError(f"{where} has {len(wps)} waypoints, the table holds {MAX_WAYPOINTS}")
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
    if data.get("version") != STATE_VERSION:
        version = _show.repr(data.get("version"))
        raise StateError(f"version is {version}, this daemon writes {STATE_VERSION}")
    motors = data.get("motors")
    if not isinstance(motors, list):
        raise StateError("'motors' is missing or not a list")
    good: list[tuple[int, SavedMotor]] = []
    bad: list[BadRecord] = []
    for i, m in enumerate(motors):
        try:
            good.append((i, parse_motor(m, f"motors[{i}]")))
        except StateError as exc:
            name = m.get("name") if isinstance(m, dict) else None
            bad.append(BadRecord(i, name if isinstance(name, str) else None, str(exc)))
    names = Counter([s.name for _, s in good] + [b.name for b in bad if b.name is not None])
    shared = {name for name, n in names.items() if n > 1}
    for i, saved in good:
        if saved.name in shared:
            bad.append(
                BadRecord(
                    i,
                    saved.name,
                    f"{names[saved.name]} motor records are named {_show.repr(saved.name)}",
                )
            )
    bad.sort(key=lambda b: b.index)
    kept = [(i, saved) for i, saved in good if saved.name not in shared]
    extra = {k: v for k, v in data.items() if k not in ("version", "motors")}
    return SavedState(
        [saved for _, saved in kept], extra, bad, {saved.name: i for i, saved in kept}
    )


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
    """The bytes of the regular file at ``path`` that is the daemon's own (daemon/paths.py:
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


# -- writing --------------------------------------------------------------------------------
def write_all(fd: int, data: bytes) -> None:
    """Write every byte, looping on short writes (a full disk raises OSError)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        if n <= 0:
            raise OSError(errno.EIO, "write returned 0")
        view = view[n:]


def fsync_dir(path: Path) -> None:
    dfd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def write_atomic(path: Path, data: bytes, mode: int = 0o640) -> None:
    """Replace ``path`` with ``data``, complete or not at all; OSError when it cannot."""
    tmp = path.with_name(path.name + ".tmp")
    fd = open_for_writing(tmp, mode, os.O_WRONLY)  # what else is there is set aside
    try:
        try:
            os.ftruncate(fd, 0)
            write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        try:
            os.replace(tmp, path)  # replaces a link or a FIFO there, never follows it
        except IsADirectoryError:  # a directory made there since the start
            clear_the_way(path)
            os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


# -- the motion journal ------------------------------------------------------------------------
class MotionJournal:
    """Write-ahead "moving" flags, one byte per motor (b"1" moving, b"0" at rest on disk).

    The byte order is the order of the motors in the state file this daemon writes, which is
    the config's order; :meth:`read` is used at start to find motors that were moving.
    """

    def __init__(self, path: Path, count: int) -> None:
        self.path = path
        self.count = count
        self._lock = threading.Lock()
        self._flags = [False] * count
        self._gen = [0] * count
        self._pending = [0] * count
        self._fd: int | None = None
        self.marks = 0
        self.mark_seconds = 0.0  # total time spent in begin()'s write + fdatasync
        self.withdrawn = 0  # flags cleared at once after a command that did not move

    @staticmethod
    def read(path: Path) -> list[bool]:
        """Which motors were marked moving ([] when there is no journal); StateError when
        the journal cannot be read or holds anything but ``0`` and ``1``."""
        try:
            raw = read_regular(path)
        except FileNotFoundError:
            return []
        if raw.strip(b"01"):
            raise StateError(f"{path} holds other bytes than 0 and 1")
        return [b == ord("1") for b in raw]

    def reset(self) -> None:
        """Start afresh, all at rest (after the state file says what is known). OSError."""
        fd = open_for_writing(self.path)  # what else is there is set aside
        try:
            os.ftruncate(fd, 0)
            write_all(fd, b"0" * self.count)
            os.fsync(fd)
        except OSError:
            os.close(fd)
            raise
        if self._fd is not None:
            os.close(self._fd)
        self._fd = fd
        with self._lock:
            self._flags = [False] * self.count
        fsync_dir(self.path.parent)

    def begin(self, index: int) -> int | None:
        """Before motor ``index`` may start: make "moving" durable. OSError when it cannot.

        Pair every successful call with :meth:`end` once the command was handled. Returns a
        token for :meth:`withdraw` when this call raised the flag (the motor was at rest on
        disk until now), else None.
        """
        with self._lock:
            self._pending[index] += 1
            self._gen[index] += 1
            if self._flags[index]:
                return None
            fd = self._fd
            token = self._gen[index]
        # The disk is waited for outside the lock: a snapshot (taken under the engine lock)
        # asks for a token meanwhile and must not wait for an fdatasync. While this start is
        # pending no token is handed out, so nothing clears the byte behind our back.
        try:
            if fd is None:
                raise OSError(errno.EBADF, "the motion journal is not open")
            t0 = time.perf_counter()
            os.pwrite(fd, b"1", index)
            os.fdatasync(fd)
            elapsed = time.perf_counter() - t0
        except OSError:
            with self._lock:
                self._pending[index] -= 1
            raise
        with self._lock:
            self.mark_seconds += elapsed
            self.marks += 1
            self._flags[index] = True
        return token

    def end(self, index: int) -> None:
        with self._lock:
            self._pending[index] -= 1

    def withdraw(self, index: int, token: int) -> bool:
        """The command whose :meth:`begin` returned ``token`` left the motor where the state
        on disk has it, at rest (a move of no distance, a refused command): clear the flag
        at once, so a kill now does not take the motor for moved. False (nothing done) when
        another start came since, or one is in flight.

        Not fsynced, as :meth:`clear_if_unchanged`: a lost clear only makes a restart more
        careful.
        """
        with self._lock:
            if self._gen[index] != token or self._pending[index] or not self._flags[index]:
                return False
            if self._fd is None:
                return False
            try:
                os.pwrite(self._fd, b"0", index)
            except OSError as exc:
                log.warning("cannot clear the motion journal %s: %s", self.path, exc.strerror)
                return False
            self._flags[index] = False
            self.withdrawn += 1
            return True

    def token(self, index: int) -> int | None:
        """Taken with the snapshot: None while a start is in flight (never clear then)."""
        with self._lock:
            return None if self._pending[index] else self._gen[index]

    def clear_if_unchanged(self, index: int, token: int | None) -> None:
        """After a durable state with the motor at rest: clear its flag unless it restarted.

        Not fsynced: a clear that is lost only makes a restart more careful.
        """
        with self._lock:
            if token is None or self._gen[index] != token or not self._flags[index]:
                return
            if self._fd is None:
                return
            try:
                os.pwrite(self._fd, b"0", index)
            except OSError as exc:
                log.warning("cannot clear the motion journal %s: %s", self.path, exc.strerror)
                return
            self._flags[index] = False

    def flagged(self) -> list[bool]:
        with self._lock:
            return list(self._flags)

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


# -- the writer --------------------------------------------------------------------------------
@dataclass
class Snapshot:
    """What the writer writes: the state, and the journal tokens of motors at rest in it."""

    state: SavedState
    at_rest: dict[int, int | None]  # motor index -> MotionJournal.token at snapshot time


class StateWriter:
    """Writes ``snapshot()`` to ``path``: on request on its own thread, or synchronously."""

    def __init__(
        self,
        path: Path,
        snapshot: Callable[[], Snapshot],
        journal: MotionJournal | None = None,
        on_change: Callable[[], None] = lambda: None,
    ) -> None:
        self.path = path
        self.snapshot = snapshot
        self.journal = journal
        self.on_change = on_change  # e.g. refresh systemd's STATUS= line
        self.writes = 0
        self.errors = 0
        self.last_error: str | None = None
        self.last_write_s = 0.0
        self.healthy = True
        self._write_lock = threading.Lock()
        self._cond = threading.Condition()
        self._requested = False
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="motorctl-state", daemon=True)

    def start(self) -> None:
        self._thread.start()

    @property
    def pending(self) -> bool:
        """A write was asked for and has not started yet (the watchdog's look)."""
        return self._requested

    def request(self) -> None:
        with self._cond:
            self._requested = True
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._requested and not self._stopping:
                    self._cond.wait()
                if not self._requested and self._stopping:
                    return
                self._requested = False
            self.write_now()

    def write_now(self) -> bool:
        """Write the newest state now; True when it is durable. Failures are logged once."""
        with self._write_lock:
            snap = self.snapshot()
            t0 = time.perf_counter()
            try:
                write_atomic(self.path, snap.state.to_bytes())
            except OSError as exc:
                self.errors += 1
                message = f"cannot write state file {self.path}: {exc.strerror or exc}"
                if self.healthy or message != self.last_error:
                    log.error(
                        "%s", message, extra={"STATE_PATH": str(self.path), "ERRNO": exc.errno}
                    )
                self.last_error = message
                was, self.healthy = self.healthy, False
                if was:
                    self.on_change()
                return False
            self.last_write_s = time.perf_counter() - t0
            self.writes += 1
            if not self.healthy:
                log.info("state file %s written again", self.path)
                self.healthy = True
                self.on_change()
            if self.journal is not None:
                for index, token in snap.at_rest.items():
                    self.journal.clear_if_unchanged(index, token)
            return True

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "file": str(self.path),
            "ok": self.healthy,
            "writes": self.writes,
            "errors": self.errors,
            "last_error": self.last_error,
            "last_write_ms": round(self.last_write_s * 1e3, 3),
        }
        if self.journal is not None:
            j = self.journal
            out["journal"] = {
                "file": str(j.path),
                "marks": j.marks,
                "withdrawn": j.withdrawn,
                "mean_mark_us": round(j.mark_seconds / j.marks * 1e6, 1) if j.marks else None,
            }
        return out

    def close(self) -> bool:
        """Stop the thread after any pending write; then write the final state."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join()
        ok = self.write_now()
        if self.journal is not None:
            self.journal.close()
        return ok


# -- the daemon's persistence: restore at start, snapshot, the dispatcher's hooks ---------------
class Persistence:
    """State of the motion engine's motors in ``directory``: restored, written, journalled.

    ``extra`` is an optional (get, set) pair for more state of the same lifetime (the mock
    world's axis positions), restored only when every motor matched.
    """

    def __init__(
        self,
        directory: Path,
        identities: Sequence[MotorIdentity],
        engine: Engine,
        extra: tuple[Callable[[], dict[str, Any]], Callable[[dict[str, Any]], None]] | None = None,
        on_change: Callable[[], None] = lambda: None,
    ) -> None:
        if len(identities) != len(engine.motors):
            raise ValueError("one identity per motor")
        self.directory = directory
        self.path = directory / STATE_NAME
        self.identities = list(identities)
        self.engine = engine
        self.extra = extra
        self.journal = MotionJournal(directory / JOURNAL_NAME, len(identities))
        self.writer = StateWriter(self.path, self.snapshot, self.journal, on_change)
        self.restored = "nothing to restore"
        self.journal_problem: str | None = None  # why the journal could not be read
        self.save_errors = 0
        self.motion_refused = 0
        # Motion commands in hand (link thread) that found their motor at rest on disk:
        # the journal's token and the position the disk has.
        self._from_rest: dict[int, tuple[int, int]] = {}

    # -- start and stop ----------------------------------------------------------------------
    def restore(self) -> None:
        """Load the state file into the motors; never raises for a bad file (see module doc)."""
        motors = self.engine.motors
        marks: list[bool] | None
        try:
            marks = MotionJournal.read(self.journal.path)
        except StateError as exc:  # logged and set aside by open(), once the state is durable
            marks, self.journal_problem = None, str(exc)
        try:
            state = read_state(self.path)
        except StateError as exc:
            self._lose_all(f"{exc}", set_aside(self.path))
            return
        if state is None:
            if marks is None:
                self._lose_all(f"{self.path} is missing and the motion journal is unreadable", None)
            elif any(marks):
                self._lose_all(
                    f"{self.journal.path} says a motor was moving and {self.path} is missing", None
                )
            return
        matches = match_motors(state, self.identities)
        moved = []
        with self.engine.lock:
            for m, match, ident in zip(motors, matches, self.identities, strict=True):
                saved = match.saved
                if saved is None:
                    m.position_lost = True
                    continue
                m.home = saved.home
                m.waypoints = list(saved.waypoints)
                m.set_position(saved.position)
                j = state.slots[ident.name]  # the journal has the file's order
                journalled = marks is None or (j < len(marks) and marks[j])
                if saved.moving or saved.position_lost or journalled:
                    m.position_lost = True
                    if not saved.position_lost:
                        moved.append(f"{m.index} ({ident.name})")
        for m, match, ident in zip(motors, matches, self.identities, strict=True):
            if match.problem is not None:
                log.warning(
                    "motor %d (%s): nothing restored from %s, %s: position lost, "
                    "home it with InitMove",
                    m.index,
                    ident.name,
                    self.path,
                    match.problem,
                    extra={"MOTOR": m.index, "STATE_PATH": str(self.path)},
                )
        if moved:
            log.warning(
                "motor %s was moving when the daemon stopped: position lost, home it with InitMove",
                ", ".join(moved),
                extra={"STATE_PATH": str(self.path)},
            )
        orphans = unmatched_records(state, self.identities)
        for what in orphans:
            log.warning(
                "%s has %s: nothing restored from that record",
                self.path,
                what,
                extra={"STATE_PATH": str(self.path)},
            )
        problems = [mt for mt in matches if mt.problem is not None]
        if problems or orphans:
            bad = set_aside(self.path)
            kept = f"kept as {bad}" if bad is not None else "could not be moved aside"
            n = len(orphans)
            unused = f", {n} record{'s' * (n != 1)} for no configured motor" if n else ""
            self.restored = (
                f"restored {len(matches) - len(problems)} of {len(matches)} "
                f"motors{unused}; the file was {kept}"
            )
        else:
            if self.extra is not None:
                self.extra[1](state.extra)
            self.restored = f"restored {len(matches)} motors"
        log.info("%s from %s", self.restored, self.path)

    def _journal_unreadable(self, bad: Path | None) -> None:
        """The one log line of an unreadable motion journal (none when it was readable)."""
        if self.journal_problem is None:
            return
        log.error(
            "motion journal unreadable: %s: every motor counts as moved; %s",
            self.journal_problem,
            f"kept it as {bad}" if bad is not None else "it stays where it is",
            extra={"STATE_PATH": str(self.journal.path)},
        )
        self.journal_problem = None

    def _lose_all(self, why: str, bad: Path | None) -> None:
        kept = f"kept it as {bad}" if bad is not None else "it stays where it is"
        log.error(
            "%s; %s; every motor must be homed again",
            why,
            kept,
            extra={"STATE_PATH": str(self.path)},
        )
        self.restored = f"nothing restored: {why}"
        with self.engine.lock:
            for m in self.engine.motors:
                m.position_lost = True

    def open(self) -> None:
        """After :meth:`restore`: write what is known now, then start the journal afresh
        (an unreadable one set aside first)."""
        if not self.writer.write_now():
            self._journal_unreadable(None)
            return  # the journal keeps what it says: a restart must still see it
        if self.journal_problem is not None:
            self._journal_unreadable(set_aside(self.journal.path))
        try:
            self.journal.reset()
        except OSError as exc:
            log.error(
                "cannot start the motion journal %s: %s; motion commands answer "
                "E4 until it can be written",
                self.journal.path,
                exc.strerror,
                extra={"STATE_PATH": str(self.journal.path), "ERRNO": exc.errno},
            )

    def start(self) -> None:
        """Start the writer thread (motor events request writes from now on)."""
        self.writer.start()

    def close(self) -> bool:
        return self.writer.close()

    # -- snapshots ------------------------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        at_rest: dict[int, int | None] = {}
        with self.engine.lock:
            motors = []
            for m, ident in zip(self.engine.motors, self.identities, strict=True):
                moving = m.active or bool(m.queue)
                if not moving:
                    at_rest[m.index] = self.journal.token(m.index)
                motors.append(
                    SavedMotor(
                        ident.name,
                        ident.fingerprint,
                        m.position,
                        m.home,
                        list(m.waypoints),
                        moving,
                        m.position_lost,
                    )
                )
            extra = self.extra[0]() if self.extra is not None else {}
        return Snapshot(SavedState(motors, extra), at_rest)

    # -- the dispatcher's hooks (link thread) ------------------------------------------------------
    def before_motion(self, index: int) -> bool:
        """Make "motor ``index`` is moving" durable before a motion command; False: cannot."""
        try:
            token = self.journal.begin(index)
        except OSError as exc:
            self.motion_refused += 1
            log.error(
                "motor %d: cannot record the start of a motion in %s: %s; answered E4",
                index,
                self.journal.path,
                exc.strerror or exc,
                extra={"MOTOR": index, "ERROR_CODE": "E4", "ERRNO": exc.errno},
            )
            return False
        if token is not None:  # from rest on disk: where the disk has it
            with self.engine.lock:
                self._from_rest[index] = (token, self.engine.motors[index].position)
        return True

    def after_motion(self, index: int) -> None:
        self.journal.end(index)
        from_rest = self._from_rest.pop(index, None)
        m = self.engine.motors[index]
        if from_rest is not None:
            token, position = from_rest
            with self.engine.lock:
                unmoved = not m.active and not m.queue and not m.stopping and m.position == position
            # A move of no distance, or a refused command: the disk is still right about
            # this motor, and a kill now must not make it lost (only a motor that really
            # moved may come back lost).
            if unmoved and self.journal.withdraw(index, token):
                return
        if not m.active:
            self.writer.request()  # let the writer clear the mark

    def save(self) -> bool:
        """SaveHome/SaveWayPoint: write now; True when the new state is durable."""
        ok = self.writer.write_now()
        if not ok:
            self.save_errors += 1
        return ok

    def status(self) -> dict[str, Any]:
        out = self.writer.status()
        out.update(
            restored=self.restored, save_errors=self.save_errors, motion_refused=self.motion_refused
        )
        return out
