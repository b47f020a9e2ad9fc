"""A read-only status socket: connect, send a request line, receive one JSON document, done;
and the summary line.

The request is one line of words, ``\n``-terminated: empty for the status, ``histogram`` for
the status with the full step-lateness histogram (``steps.histogram_us``, up to 20,001 bins:
built and encoded only when asked). A client that sends nothing gets the plain status after
``REQUEST_WAIT_S`` (``socat - UNIX-CONNECT:status.sock`` works).

Threads: :class:`StatusServer` owns one thread that serves every client with non-blocking
sockets from one selector: it blocks only in ``select()``, so a client that is slow to ask
or to read holds up nobody (it is dropped after ``SEND_TIMEOUT_S``); at most
``MAX_CLIENTS`` at once, the rest wait in the listen backlog. An ``accept()`` error other
than the socket being closed is logged and retried after a pause, never the end of the
server. ``status()`` is called on that thread and takes no lock of the motion engine: a
read of its own snapshots, bounded in cost (docs/service.md).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import selectors
import socket
import threading
import time
from pathlib import Path
from typing import Any, Protocol

log = logging.getLogger("motorctl.status")

SEND_TIMEOUT_S = 2.0
REQUEST_WAIT_S = 0.5
ACCEPT_RETRY_S = 0.2
MAX_CLIENTS = 16
MAX_REQUEST = 256
REQUESTS = ("histogram",)


class StatusSource(Protocol):
    """Builds the status document; ``histogram``: with ``steps.histogram_us``."""

    def __call__(self, histogram: bool = False) -> dict[str, Any]: ...


class _Client:
    __slots__ = ("deadline", "events", "out", "request", "sock")

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock = sock
        self.request = b""
        self.out: memoryview | None = None  # the answer, once the request is in
        self.deadline = deadline
        self.events = 0  # what the selector watches for it (0: not registered)


class StatusServer:
    def __init__(self, path: Path, status: StatusSource) -> None:
        """Bind ``path`` (the caller holds the instance lock: a socket there is stale)."""
        self.path = path
        self.status = status
        self.errors = 0
        self.served = 0
        if path.is_socket():
            path.unlink()
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self._sock.bind(str(path))
        os.chmod(path, 0o660)  # the service's group may ask (connecting needs write)
        st = os.lstat(path)
        self.identity = (st.st_dev, st.st_ino, st.st_ctime_ns)
        self._sock.listen(MAX_CLIENTS)
        self._sock.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._closed = threading.Event()
        self._clients: dict[int, _Client] = {}
        self._sel = selectors.DefaultSelector()
        self._accepting = False
        self._resume_accept = 0.0
        self._thread = threading.Thread(target=self._run, name="motorctl-status", daemon=True)

    def start(self) -> None:
        self._thread.start()

    # -- the server's thread -----------------------------------------------------------
    # Few system calls per read: each one lets the step thread (thread executor) take the
    # GIL, and getting it back costs up to a switch interval. A client that asked at once
    # is answered straight from accept(), without the selector.
    def _run(self) -> None:
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._accept_on(True)
        try:
            while not self._closed.is_set():
                now = time.monotonic()
                due = [c.deadline for c in self._clients.values()]
                if not self._accepting and len(self._clients) < MAX_CLIENTS:
                    due.append(self._resume_accept)
                timeout = max(0.0, min(due) - now) if due else None
                for key, _ in self._sel.select(timeout):
                    if key.fileobj is self._wake_r:
                        return
                    if key.fileobj is self._sock:
                        self._accept()
                    elif isinstance(key.data, _Client):
                        self._serve(key.data)
                self._expire(time.monotonic())
        finally:
            for client in list(self._clients.values()):
                self._drop(client)
            self._sel.close()

    def _accept_on(self, on: bool) -> None:
        if on and not self._accepting:
            self._sel.register(self._sock, selectors.EVENT_READ, None)
        elif not on and self._accepting:
            self._sel.unregister(self._sock)
        self._accepting = on

    def _accept(self) -> None:
        """One client (more pending: the selector says so again at once)."""
        try:
            conn, _ = self._sock.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            if self._closed.is_set():
                return
            self.errors += 1
            log.warning("status socket %s: accept failed: %s; retrying", self.path, exc)
            self._accept_on(False)  # e.g. EMFILE: the listener stays readable
            self._resume_accept = time.monotonic() + ACCEPT_RETRY_S
            return
        conn.setblocking(False)
        client = _Client(conn, time.monotonic() + REQUEST_WAIT_S)
        self._clients[conn.fileno()] = client
        if len(self._clients) >= MAX_CLIENTS:
            self._accept_on(False)  # full: the rest wait in the backlog
        self._serve(client)

    def _serve(self, client: _Client) -> None:
        """Take the request, answer it, as far as it goes without blocking; then let the
        selector watch for what it waits for."""
        if client.out is None:
            try:
                chunk = client.sock.recv(MAX_REQUEST)
            except (BlockingIOError, InterruptedError):
                self._watch(client, selectors.EVENT_READ)
                return
            except OSError:
                self._drop(client)
                return
            client.request += chunk
            if chunk and b"\n" not in client.request and len(client.request) <= MAX_REQUEST:
                self._watch(client, selectors.EVENT_READ)
                return
            self._answer(client)  # a line, the end of input, or too long
        self._send(client)

    def _answer(self, client: _Client) -> None:
        client.out = memoryview(self.document(client.request))
        client.deadline = time.monotonic() + SEND_TIMEOUT_S

    def _send(self, client: _Client) -> None:
        assert client.out is not None
        try:
            sent = client.sock.send(client.out)
        except (BlockingIOError, InterruptedError):
            self._watch(client, selectors.EVENT_WRITE)
            return
        except OSError:
            self._drop(client)
            return
        client.out = client.out[sent:]
        if client.out:
            self._watch(client, selectors.EVENT_WRITE)
            return
        self.served += 1
        self._drop(client)

    def _watch(self, client: _Client, events: int) -> None:
        if client.events == events:
            return
        if client.events:
            self._sel.modify(client.sock, events, client)
        else:
            self._sel.register(client.sock, events, client)
        client.events = events

    def _expire(self, now: float) -> None:
        for client in list(self._clients.values()):
            if client.deadline <= now:
                if client.out is None:
                    self._answer(client)  # asked nothing: the plain status
                    self._send(client)
                else:
                    self._drop(client)  # not reading its answer
        if not self._accepting and len(self._clients) < MAX_CLIENTS \
                and now >= self._resume_accept:
            self._accept_on(True)

    def _drop(self, client: _Client) -> None:
        self._clients.pop(client.sock.fileno(), None)
        if client.events:
            self._sel.unregister(client.sock)
            client.events = 0
        client.sock.close()

    def document(self, request: bytes) -> bytes:
        """The answer to one request line: the status as JSON, or an error document."""
        words = request.split(b"\n", 1)[0].decode("ascii", "replace").split()
        unknown = [w for w in words if w not in REQUESTS]
        if unknown or len(request) > MAX_REQUEST:
            what = " ".join(unknown) if unknown else "a request line too long"
            return json.dumps({"error": f"unknown status request: {what}; "
                                        f"known: {', '.join(REQUESTS)}"}).encode()
        try:
            return json.dumps(self.status(histogram="histogram" in words),
                              sort_keys=True).encode()
        except Exception:
            log.exception("cannot build the status document")
            return json.dumps({"error": "status unavailable, see the log"}).encode()

    def close(self) -> None:
        """Stop serving and remove the socket if it is still ours; never raises."""
        self._closed.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._thread.is_alive():
            self._thread.join(2.0)
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        self._wake_r.close()
        self._wake_w.close()
        try:
            st = os.lstat(self.path)
            if (st.st_dev, st.st_ino, st.st_ctime_ns) == self.identity:
                os.unlink(self.path)
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("cannot remove status socket %s: %s", self.path, exc.strerror)


def read_status(path: Path, timeout: float = 5.0, histogram: bool = False) -> dict[str, Any]:
    """The daemon's status; ``histogram``: with ``steps.histogram_us`` (costlier: ask only
    when needed)."""
    deadline = time.monotonic() + timeout
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        while True:
            try:
                sock.connect(str(path))
                break
            except BlockingIOError:  # the server's backlog is full: a slot frees soon
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"{path}: every status slot stayed busy for "
                                       f"{timeout:.0f} s") from None
                time.sleep(0.005)
        sock.sendall(b"histogram\n" if histogram else b"\n")
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
        if link.get("peer") == "gone":
            parts.append("SERIAL DEVICE GONE, reopening it")
    state = status.get("state")
    if isinstance(state, dict) and not state.get("ok", True):
        parts.append("STATE NOT SAVED: " + str(state.get("last_error")))
    return "; ".join(parts)
