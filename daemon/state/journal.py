"""The motion journal: "moving" made durable before a motion command is acknowledged.

A motion command must not be acknowledged while the state on disk still says its motor is
at rest (a SIGKILL right then would restore a stale position). :class:`MotionJournal` is a
write-ahead record of one byte per motor (``state.moving``), set and fdatasynced before the
motion starts; the state writer (daemon/state/writer.py) clears it once a state file with
the motor at rest again is durable. A command that found its motor at rest on disk and left
it there (a move of no distance, a refused command) clears the byte itself before it is
answered (``withdraw``), since the state on disk is still right: only a motor that really
moved may come back lost. A motor whose byte is set when the daemon starts has lost its
position (daemon/state/persistence.py). The journal is opened as every file the daemon
writes (daemon/state/files.py); one that cannot be read is set aside once the state file
written after it is durable.

Threads: called by the link thread (``begin``/``end``/``withdraw``) and the writer thread
(``clear_if_unchanged``), and by a snapshot under the engine lock (``token``); it guards
itself with a lock. ``begin`` blocks on one ``fdatasync`` of a tiny file, outside that
lock, and only when the motor was at rest on disk.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
from pathlib import Path

from motorctl.daemon.state.files import fsync_dir, open_for_writing, write_all
from motorctl.daemon.state.records import StateError, read_regular

log = logging.getLogger("motorctl.state")


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
