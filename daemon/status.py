"""A read-only status socket: connect, receive one JSON document, done; and the summary line.

Threads: :class:`StatusServer` owns one thread that accepts and answers, one client at a
time; it blocks in ``accept()`` and on sending to a slow client (bounded by a timeout). An
``accept()`` error other than the socket being closed is logged and retried after a pause,
never the end of the server. ``status()`` is called on that thread and must only take
short locks.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

log = logging.getLogger("motorctl.status")

SEND_TIMEOUT_S = 2.0
ACCEPT_RETRY_S = 0.2


class StatusServer:
    def __init__(self, path: Path, status: Callable[[], dict[str, Any]]) -> None:
        """Bind ``path`` (the caller holds the instance lock: a socket there is stale)."""
        self.path = path
        self.status = status
        self.errors = 0
        if path.is_socket():
            path.unlink()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self._sock.bind(str(path))
        os.chmod(path, 0o660)  # the service's group may ask (connecting needs write)
        st = os.lstat(path)
        self.identity = (st.st_dev, st.st_ino, st.st_ctime_ns)
        self._sock.listen(4)
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="motorctl-status", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while not self._closed.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError as exc:
                if self._closed.is_set():
                    return
                self.errors += 1
                log.warning("status socket %s: accept failed: %s; retrying", self.path, exc)
                self._closed.wait(ACCEPT_RETRY_S)
                continue
            with conn:
                self.serve_one(conn)

    def serve_one(self, conn: socket.socket) -> None:
        try:
            data = json.dumps(self.status(), sort_keys=True).encode()
        except Exception:
            log.exception("cannot build the status document")
            data = json.dumps({"error": "status unavailable, see the log"}).encode()
        with contextlib.suppress(OSError):
            conn.settimeout(SEND_TIMEOUT_S)
            conn.sendall(data)

    def close(self) -> None:
        """Stop serving and remove the socket if it is still ours; never raises."""
        self._closed.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        if self._thread.is_alive():
            self._thread.join(2.0)
        try:
            st = os.lstat(self.path)
            if (st.st_dev, st.st_ino, st.st_ctime_ns) == self.identity:
                os.unlink(self.path)
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("cannot remove status socket %s: %s", self.path, exc.strerror)


def read_status(path: Path, timeout: float = 5.0) -> dict[str, Any]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(str(path))
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    data = json.loads(b"".join(chunks))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the status is not a JSON object")
    return data


def summary_line(status: dict[str, Any]) -> str:
    """systemd's STATUS=: motors moving/faulted/lost, frames served, errors, state file."""
    motors = status.get("motors", [])
    moving = sum(1 for m in motors if m.get("state") not in ("idle", "fault"))
    faulted = [str(m.get("index")) for m in motors if m.get("fault")]
    lost = sum(1 for m in motors if m.get("position_lost"))
    parts = [f"{len(motors)} motors: {moving} moving"]
    parts[0] += f", faulted {','.join(faulted)}" if faulted else ", none faulted"
    if lost:
        parts[0] += f", {lost} to home"
    link = status.get("link")
    if isinstance(link, dict):
        counters = link.get("counters", {})
        errors = sum(v for k, v in counters.items()
                     if isinstance(v, int) and (k.endswith("_errors") or k.startswith("sent_")))
        parts.append(f"{counters.get('responses', 0)} frames served, {errors} errors")
    state = status.get("state")
    if isinstance(state, dict) and not state.get("ok", True):
        parts.append("STATE NOT SAVED: " + str(state.get("last_error")))
    return "; ".join(parts)
