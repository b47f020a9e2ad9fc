"""Persistence: home positions, waypoints and positions of motors at rest.

The state file lives under the runtime directory (default /run/motorctl, a tmpfs:
it survives a daemon restart and is gone after a reboot, like a microcontroller's
RAM). Every write is atomic: a temporary file, fsync, rename, fsync of the folder.
Writes happen on a writer thread so neither the link nor the step thread waits
for the disk; each change requests a write and the writer writes the newest state.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

log = logging.getLogger("motorctl.state")

STATE_VERSION = 1


class StateError(Exception):
    pass


def write_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    text = json.dumps(data, indent=1, sort_keys=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        os.write(fd, text.encode())
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def read_state(path: Path) -> dict[str, Any] | None:
    """The saved state, None when there is none; StateError when it is unreadable."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StateError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict) or data.get("version") != STATE_VERSION:
        raise StateError(f"{path}: not a motorctl state file of version {STATE_VERSION}")
    if not isinstance(data.get("motors"), list):
        raise StateError(f"{path}: 'motors' missing")
    return data


class StateWriter:
    """Writes ``snapshot()`` to ``path`` on request, on its own thread."""

    def __init__(self, path: Path, snapshot: Callable[[], dict[str, Any]]) -> None:
        self.path = path
        self.snapshot = snapshot
        self.writes = 0
        self.errors = 0
        self._cond = threading.Condition()
        self._requested = False
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="motorctl-state", daemon=True)

    def start(self) -> None:
        self._thread.start()

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

    def write_now(self) -> None:
        try:
            write_atomic(self.path, self.snapshot())
            self.writes += 1
        except OSError as exc:
            self.errors += 1
            log.error("cannot write state file %s: %s", self.path, exc)

    def close(self) -> None:
        """Stop the thread after any pending write; then write the final state."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join()
        self.write_now()
