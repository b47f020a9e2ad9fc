"""The status socket's clients: the status once (:func:`read_status`), or its updates as they
come (:func:`subscribe`; docs/status.md). ``motorctld --status``, the live monitor, the
benchmarks and the tests read the daemon through these.

The protocol (request words, one JSON document per line, the heartbeat) is the server's
(daemon/status/server.py); these follow it.

Threads: the caller's; each call has its own connection and blocks on it (bounded by
``timeout``).
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Generator
from pathlib import Path
from typing import Any

from motorctl.daemon.status.server import HEARTBEAT_S


def _connect(sock: socket.socket, path: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            sock.connect(str(path))
            return
        except BlockingIOError:  # the server's backlog is full: a slot frees soon
            if time.monotonic() >= deadline:
                raise TimeoutError(
                    f"{path}: every status slot stayed busy for {timeout:.0f} s"
                ) from None
            time.sleep(0.005)


def read_status(path: Path, timeout: float = 5.0, histogram: bool = False) -> dict[str, Any]:
    """The daemon's status; ``histogram``: with ``steps.histogram_us`` (costlier: ask only
    when needed)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        _connect(sock, path, timeout)
        sock.sendall(b"histogram\n" if histogram else b"\n")
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    data = json.loads(b"".join(chunks))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the status is not a JSON object")
    return data


class StatusError(Exception):
    """The status socket answered with an error document (its text is the message)."""


def subscribe(
    path: Path, period_s: float | None = None, timeout: float = 5.0
) -> Generator[dict[str, Any], None, None]:
    """The daemon's status updates as they come (docs/status.md), until the daemon closes
    the stream (it stopped: the iterator ends). ``period_s``: how often the daemon looks
    for a change (None: its default). OSError when it cannot connect; TimeoutError when no
    update came for three heartbeats; StatusError for an error document."""
    request = (
        b"subscribe\n" if period_s is None else f"subscribe {round(period_s * 1000)}\n".encode()
    )
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        _connect(sock, path, timeout)
        sock.sendall(request)
        sock.settimeout(3 * HEARTBEAT_S + timeout)
        buffered = b""
        while True:
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                raise TimeoutError(
                    f"{path}: no status update for {3 * HEARTBEAT_S + timeout:.0f} s"
                ) from None
            if not chunk:
                if buffered.strip():  # an answer without a line end: an error document
                    yield _update_of(buffered, path)
                return
            buffered += chunk
            *lines, buffered = buffered.split(b"\n")
            for line in lines:
                yield _update_of(line, path)


def _update_of(line: bytes, path: Path) -> dict[str, Any]:
    data = json.loads(line)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a status update is not a JSON object")
    if set(data) == {"error"}:
        raise StatusError(str(data["error"]))
    return data
