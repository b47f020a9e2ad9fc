"""The status socket's clients: the status once (:func:`read_status`), its updates as they
come (:func:`subscribe`; docs/status.md), or the status again and again over one kept
connection (:class:`StatusReader`: for a reader that reads often; a read costs the daemon
less than half of a one-shot read: docs/timing.md). ``motorctld --status``, the live
monitor, the benchmarks and the tests read the daemon through these; :func:`unreachable`
says why none came, and what to do.

The protocol (request words, one JSON document per line, the heartbeat) is the server's
(daemon/status/server.py); these follow it.

Threads: the caller's; each call has its own connection and blocks on it (bounded by
``timeout``); a :class:`StatusReader` holds one connection for one thread at a time.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import time
from collections.abc import Generator
from pathlib import Path
from typing import Any

from motorctl.daemon.state.files import SOCKET_PATH_MAX
from motorctl.daemon.status.requests import HEARTBEAT_S


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


#: what connecting to a status socket that nobody serves fails with: nothing there (or a
#: state directory that is a file), a stale socket, something else at its path
NOBODY_THERE = frozenset({errno.ENOENT, errno.ENOTDIR, errno.ECONNREFUSED, errno.ENOTSOCK})


def unreachable(path: Path, exc: BaseException) -> str:
    """Why :func:`read_status` found no status at ``path``, in words to put after it:
    for a socket that nobody serves, what to do (start the daemon, or name the state
    directory it runs with); for one that may not be opened, whose group to join."""
    if isinstance(exc, OSError) and exc.errno in NOBODY_THERE:
        return (
            f"{exc.strerror}: no motorctld serves its status there; start it, or give "
            "--state-dir the state directory it runs with (default /run/motorctl)"
        )
    if isinstance(exc, OSError) and exc.errno in (errno.EACCES, errno.EPERM):
        return f"{exc.strerror}: {_group_fix(path)}"
    if "AF_UNIX path too long" in str(exc):
        return (
            f"{exc}: a Unix socket's path holds at most {SOCKET_PATH_MAX} bytes, so no "
            "motorctld serves one there; give --state-dir the shorter path it runs with"
        )
    if isinstance(exc, OSError) and exc.strerror and exc.errno is not None:
        return exc.strerror
    return str(exc)


def _group_fix(path: Path) -> str:
    """Whose group may read a status socket at ``path`` (0660), and how to join it."""
    import grp

    try:
        gid = os.stat(path).st_gid
        group = grp.getgrgid(gid).gr_name
    except (OSError, KeyError):
        return "the status socket is open to its owner and group only (ls -l it)"
    return (
        f"the status socket is open to its owner and group {group} only; join the group "
        f"with 'sudo adduser $USER {group}' and log in again"
    )


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


class _Closed(Exception):
    """The daemon closed a kept connection (it stopped, or closed it: idle, or another
    reader took its place); ``args[0]``: what came after the last whole line."""


class StatusReader:
    """The daemon's status, read as often as asked over one kept connection (the ``keep``
    request, docs/status.md): :meth:`read` answers as :func:`read_status` does, without a
    connection per read. When the daemon closed the connection (it restarted, or closed
    one that asked nothing for ``KEEP_IDLE_S``, or another reader took its place) the next
    read connects again on its own, once. OSError naming the path and the fix when no
    daemon answers there; TimeoutError naming the path when one connects but does not
    answer within ``timeout``; StatusError when a daemon refuses to keep the connection
    (one older than the ``keep`` request)."""

    def __init__(self, path: Path, timeout: float = 5.0) -> None:
        self.path = path
        self.timeout = timeout
        self.connects = 0  # connections made (the first, and one per reconnect)
        self._sock: socket.socket | None = None
        self._buffered = b""

    def read(self, histogram: bool = False) -> dict[str, Any]:
        """The status; ``histogram``: with ``steps.histogram_us`` (costlier)."""
        request = b"histogram\n" if histogram else b"\n"
        if self._sock is not None:
            try:
                return self._ask(self._sock, request)
            except (ConnectionError, _Closed):
                self.close()  # closed by the daemon: once more on a new connection
        sock = self._connect()
        try:
            return self._ask(sock, b"keep\n" + request)
        except (ConnectionError, _Closed) as exc:
            self.close()
            refusal = _refusal(exc)
            if refusal is not None:  # a daemon older than 'keep' says so and closes
                raise StatusError(
                    f"{self.path}: the daemon refused a kept connection: {refusal}"
                ) from None
            raise ConnectionError(
                errno.ECONNRESET,
                f"{self.path}: the daemon closed a new status connection without an answer "
                f"({exc or 'closed'}): it is stopping, or older than the 'keep' request; "
                "read_status() reads once per connection",
            ) from None

    def _connect(self) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        try:
            _connect(sock, self.path, self.timeout)
        except (FileNotFoundError, ConnectionRefusedError) as exc:
            sock.close()
            raise type(exc)(
                exc.errno,
                f"{self.path}: no motorctld serves its status there ({exc.strerror}): start "
                "it, or give the state directory it runs with (--state-dir)",
            ) from None
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._buffered = b""
        self.connects += 1
        return sock

    def _ask(self, sock: socket.socket, request: bytes) -> dict[str, Any]:
        try:
            sock.sendall(request)
            buffered = self._buffered
            while (end := buffered.find(b"\n")) < 0:
                chunk = sock.recv(65536)
                if not chunk:
                    raise _Closed(buffered)
                buffered += chunk
        except TimeoutError:
            self.close()  # what came late would be taken for the next read's answer
            raise TimeoutError(
                f"{self.path}: the status did not come within {self.timeout:g} s"
            ) from None
        self._buffered = buffered[end + 1 :]
        data = json.loads(buffered[:end])
        if not isinstance(data, dict):
            raise ValueError(f"{self.path}: the status is not a JSON object")
        return data

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self._buffered = b""

    def __enter__(self) -> StatusReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _refusal(exc: Exception) -> str | None:
    """The error document that came without a line end before the close, if any."""
    rest = exc.args[0] if isinstance(exc, _Closed) and exc.args else b""
    try:
        data = json.loads(rest) if rest.strip() else None
    except ValueError:
        return None
    return str(data["error"]) if isinstance(data, dict) and "error" in data else None
