"""Persistence: home positions, waypoints and positions of motors at rest, kept across restarts.

:class:`Persistence` ties the state wing together for the daemon: at start it restores the
state file into the motors (daemon/state/records.py says what is trusted) and sets the file
aside when anything was not restored, under the first free name of ``state.json.bad``,
``state.json.bad.1``, ... (never replacing an older one), naming it in the log; then it
writes what is known and starts the motion journal afresh (daemon/state/journal.py). While
serving it takes snapshots for the writer (daemon/state/writer.py) and gives the dispatcher
its hooks: ``before_motion``/``after_motion`` around every motion command (the journal's
write-ahead byte) and ``save`` for SaveHome/SaveWayPoint (answered after the write).

Threads: ``restore`` and ``open`` run on the main thread at start-up; the dispatcher's hooks
on the link thread; ``snapshot`` on the writer's thread and the link thread's saves.
``Persistence`` takes the engine lock briefly for a snapshot, and before and after a motion
from rest (where was the motor, did it move).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from motorctl.daemon.state.files import set_aside
from motorctl.daemon.state.journal import MotionJournal
from motorctl.daemon.state.records import (
    JOURNAL_NAME,
    STATE_NAME,
    Match,
    MotorIdentity,
    SavedMotor,
    SavedState,
    StateError,
    match_motors,
    read_state,
    unmatched_records,
)
from motorctl.daemon.state.writer import Snapshot, StateWriter

if TYPE_CHECKING:
    from motorctl.motion.engine import MotionEngine as Engine

log = logging.getLogger("motorctl.state")


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
        """Load the state file into the motors; never raises for a bad file (see module doc).

        In steps: the journal's marks, the state file, each motor's match loaded into it,
        the warnings of what was not restored, then the outcome (the file set aside when
        anything was not).
        """
        marks = self._journal_marks()
        state = self._saved_state(marks)
        if state is None:
            return
        matches = match_motors(state, self.identities)
        moved = self._load_motors(state, matches, marks)
        orphans = unmatched_records(state, self.identities)
        self._warn(matches, moved, orphans)
        self.restored = self._outcome(state, matches, orphans)
        log.info("%s from %s", self.restored, self.path)

    def _journal_marks(self) -> list[bool] | None:
        """Which of the file's motors the motion journal says were moving; None when it
        cannot be read (its problem kept for :meth:`open`, which logs it and sets it aside
        once the state is durable)."""
        try:
            return MotionJournal.read(self.journal.path)
        except StateError as exc:
            self.journal_problem = str(exc)
            return None

    def _saved_state(self, marks: list[bool] | None) -> SavedState | None:
        """The state file, None when there is none to restore (every motor lost when that
        is for a reason: the file cannot be trusted, or it is missing and the journal says
        a motor may have moved)."""
        try:
            state = read_state(self.path)
        except StateError as exc:
            self._lose_all(f"{exc}", set_aside(self.path))
            return None
        if state is None:
            if marks is None:
                self._lose_all(f"{self.path} is missing and the motion journal is unreadable", None)
            elif any(marks):
                self._lose_all(
                    f"{self.journal.path} says a motor was moving and {self.path} is missing", None
                )
        return state

    def _load_motors(
        self, state: SavedState, matches: Sequence[Match], marks: list[bool] | None
    ) -> list[str]:
        """Each motor its match: a motor without one has lost its position; one with one
        gets its home, table and position, and loses the position when it was moving (the
        record or the journal says so). The motors that were moving, named for the log."""
        moved = []
        with self.engine.lock:
            for m, match, ident in zip(self.engine.motors, matches, self.identities, strict=True):
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
        return moved

    def _warn(self, matches: Sequence[Match], moved: list[str], orphans: list[str]) -> None:
        """The log's warnings: each motor nothing was restored for, the motors that were
        moving, each record of no configured motor."""
        for m, match, ident in zip(self.engine.motors, matches, self.identities, strict=True):
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
        for what in orphans:
            log.warning(
                "%s has %s: nothing restored from that record",
                self.path,
                what,
                extra={"STATE_PATH": str(self.path)},
            )

    def _outcome(self, state: SavedState, matches: Sequence[Match], orphans: list[str]) -> str:
        """What was restored, in words: the file set aside when anything of it was not;
        when everything was, the extra state restored too."""
        problems = [mt for mt in matches if mt.problem is not None]
        if problems or orphans:
            bad = set_aside(self.path)
            kept = f"kept as {bad}" if bad is not None else "could not be moved aside"
            n = len(orphans)
            unused = f", {n} record{'s' * (n != 1)} for no configured motor" if n else ""
            return (
                f"restored {len(matches) - len(problems)} of {len(matches)} "
                f"motors{unused}; the file was {kept}"
            )
        if self.extra is not None:
            self.extra[1](state.extra)
        return f"restored {len(matches)} motors"

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
