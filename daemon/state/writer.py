"""The state writer: the newest state written, complete or absent, off the motors' threads.

:class:`StateWriter` writes a :class:`Snapshot` (the state, and the journal tokens of the
motors at rest in it) with daemon/state/files.py's :func:`write_atomic`, then clears the
motion journal's bytes of the motors that stayed at rest (daemon/state/journal.py). A failed
write is logged once per episode and counted; the status shows it.

Threads: :class:`StateWriter` writes on its own thread (``motorctl-state``) on request
(motor events, which come from the step thread and must not wait for a disk) and
synchronously when asked by the link thread (SaveHome/SaveWayPoint, answered only after the
write). Its write lock serialises both. ``status()`` may be called from the status thread
(it copies counters).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from motorctl.daemon.state.files import write_atomic
from motorctl.daemon.state.journal import MotionJournal
from motorctl.daemon.state.records import SavedState

log = logging.getLogger("motorctl.state")


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
