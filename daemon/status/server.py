"""The status socket's server: connect, send a request line, receive one JSON document,
done; or subscribe and receive one JSON document per line for as long as you stay; or keep
the connection and ask again and again, one JSON document per line for each request line.

The requests and what is kept of each connection are daemon/status/requests.py's (its
clients, daemon/status/reader.py, follow the same protocol); the document itself is built
by daemon/status/document.py (the assembler hands it a ``StatusDocument``: each read builds
again only what may have changed) and encoded by daemon/status/encoder.py (only what
changed is encoded again). A subscriber's updates are looked for every PERIOD_MS and at
once when a motor starts, stops or faults (:meth:`StatusServer.poke`). A client that sends
nothing gets the plain status after ``REQUEST_WAIT_S`` (``socat - UNIX-CONNECT:status.sock``
works).

Threads: :class:`StatusServer` owns one thread that serves every client from one epoll
set, never waiting on a client (each is asked with ``MSG_DONTWAIT``): it blocks only in
``epoll_wait()``, so a client that is slow to ask or to read holds up nobody (it is
dropped after ``SEND_TIMEOUT_S``); at most ``MAX_CLIENTS`` at once, the rest wait in the
listen backlog; of these at most ``MAX_SUBSCRIBERS`` subscribers, so one-shot reads always
find a slot; when they are all taken, a new subscriber takes the place of the oldest one
that does not read its updates (:meth:`StatusServer._evict_one`). A subscriber that has
not taken an update within ``SEND_TIMEOUT_S`` is dropped; while one is still being sent,
newer ones are not queued behind it (it gets the state of its next turn). At most
``MAX_KEPT`` kept connections (a new one replaces the one that asked longest ago), each
closed after ``KEEP_IDLE_S`` without a request or ``SEND_TIMEOUT_S`` with an answer
unread; its requests wait unread in its socket while an answer is being sent. An
``accept()`` error other than the socket being closed is logged and retried after a pause,
never the end of the server. ``status()`` is called on that thread and takes no lock of the
motion engine: a read of its own snapshots, bounded in cost (docs/service.md).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import select
import socket
import struct
import termios
import threading
import time
from pathlib import Path
from typing import Any, Protocol

from motorctl.daemon.state.files import bind_socket
from motorctl.daemon.status.encoder import DocumentEncoder
from motorctl.daemon.status.requests import (
    HEARTBEAT_S,
    MAX_REQUEST,
    PLAIN,
    Client,
    Request,
    Subscription,
    kept_request,
    parse_request,
    stable_view,
)

log = logging.getLogger("motorctl.status")

SEND_TIMEOUT_S = 2.0
REQUEST_WAIT_S = 0.5
ACCEPT_RETRY_S = 0.2
MAX_CLIENTS = 16
MAX_SUBSCRIBERS = 8
MAX_KEPT = 4  # kept connections: with the subscribers, one-shot reads still find a slot
KEEP_IDLE_S = 10.0  # a kept connection that asks nothing this long is closed
SUBSCRIBE_MIN_GAP_S = 0.02  # motor events make updates no more often than this


class StatusSource(Protocol):
    """Builds the status document; ``histogram``: with ``steps.histogram_us``."""

    def __call__(self, histogram: bool = False) -> dict[str, Any]: ...


def unread_bytes(sock: socket.socket) -> int:
    """What the peer has not read yet of what was sent on ``sock`` (Linux: SIOCOUTQ, which
    counts the kernel's buffers, a little more than the bytes); 0 where it cannot tell."""
    try:
        raw = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0")
    except OSError:
        return 0
    value: int = struct.unpack("i", raw)[0]
    return value


class _Listener(socket.socket):
    """The status socket's listening socket: :meth:`accept` gives each connection in
    blocking mode (the server asks it with ``MSG_DONTWAIT``: no ``ioctl`` to make it
    non-blocking), without ``socket.socket.accept``'s work in Python (its enums): a status
    read is mostly this work per connection (docs/timing.md)."""

    __slots__ = ()

    def accept(self) -> tuple[socket.socket, Any]:
        fd, addr = self._accept()  # type: ignore[attr-defined]  # (socket.py's own way)
        try:
            return socket.socket(socket.AF_UNIX, socket.SOCK_STREAM, 0, fd), addr
        except OSError:
            os.close(fd)
            raise


#: ``recv``/``send`` flags on a client's socket: never wait (the server's thread serves all)
NOWAIT = socket.MSG_DONTWAIT


class StatusServer:
    def __init__(self, path: Path, status: StatusSource) -> None:
        """Bind ``path`` (the caller holds the instance lock: a socket there is stale;
        anything else there is set aside, daemon/state/files.py). OSError when it cannot."""
        self.path = path
        self.status = status
        # the documents as JSON, what is unchanged since the last one kept encoded: the
        # documents sent, and the stable views that decide a subscriber's update
        self._encoder = DocumentEncoder()
        self._stable_encoder = DocumentEncoder()
        self._sent: tuple[dict[str, Any], bytes] | None = None  # the last document, encoded
        self.errors = 0
        self.served = 0
        self.evicted = 0  # subscribers closed to let a new one in (not reading theirs)
        self.kept = 0  # kept connections now
        self.kept_evicted = 0  # kept connections closed to let a new one in
        # 0660: the service's group may ask (connecting needs write)
        bound = bind_socket(path, 0o660)
        self._sock = _Listener(socket.AF_UNIX, socket.SOCK_STREAM, 0, bound.detach())
        st = os.lstat(path)
        self.identity = (st.st_dev, st.st_ino, st.st_ctime_ns)
        self._sock.listen(MAX_CLIENTS)
        self._sock.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_w.setblocking(False)  # poke() from the step thread never blocks
        self.subscribers = 0
        self._closed = threading.Event()
        self._clients: dict[int, Client] = {}  # by descriptor
        self._ep = select.epoll()  # the wake-up socket, the listener (while accepting), clients
        self._accepting = False
        self._resume_accept = 0.0
        self._thread = threading.Thread(target=self._run, name="motorctl-status", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def poke(self) -> None:
        """Something changed that subscribers should see at once (a motor started, stopped
        or faulted). Any thread, never blocks, costs nothing without subscribers."""
        if self.subscribers:
            with contextlib.suppress(OSError):
                self._wake_w.send(b"p")

    # -- the server's thread -----------------------------------------------------------
    # Few system calls and little Python per read (a read is mostly this work, not the
    # document: docs/timing.md), and each system call lets the step thread (thread
    # executor) take the GIL, getting it back costing up to a switch interval. A client
    # that asked at once is answered straight from accept(), never registered; a client's
    # socket is a bare one asked with MSG_DONTWAIT (no ioctl to make it non-blocking); a
    # client's descriptor leaves the epoll set with its close (no EPOLL_CTL_DEL). An event
    # for a descriptor closed and reused in the same turn reaches the new client, whose
    # MSG_DONTWAIT call finds nothing to do: harmless.
    def _run(self) -> None:
        wake = self._wake_r.fileno()
        listener = self._sock.fileno()
        clients = self._clients
        self._ep.register(wake, select.EPOLLIN)
        self._accept_on(True)
        try:
            while not self._closed.is_set():
                if clients or not self._accepting:
                    now = time.monotonic()
                    due = [
                        c.sub.due if c.sub is not None and c.out is None else c.deadline
                        for c in clients.values()
                    ]
                    if not self._accepting and len(clients) < MAX_CLIENTS:
                        due.append(self._resume_accept)
                    timeout = max(0.0, min(due) - now) if due else -1.0
                else:
                    timeout = -1.0  # nobody connected: only a connection or a poke wakes it
                for fd, _ in self._ep.poll(timeout):
                    if fd == listener:
                        self._accept()
                    elif fd == wake:
                        if self._closed.is_set():
                            return
                        self._poked()
                    else:
                        client = clients.get(fd)
                        if client is not None:
                            self._serve(client)
                if clients or not self._accepting:
                    self._expire(time.monotonic())
        finally:
            for client in list(clients.values()):
                self._drop(client)
            self._ep.close()

    def _accept_on(self, on: bool) -> None:
        if on and not self._accepting:
            self._ep.register(self._sock.fileno(), select.EPOLLIN)
        elif not on and self._accepting:
            self._ep.unregister(self._sock.fileno())
        self._accepting = on

    def _accept(self) -> None:
        """One client (more pending: the epoll says so again at once); a plain request
        already whole is answered here, the client never registered."""
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
        try:
            chunk: bytes | None = conn.recv(MAX_REQUEST, NOWAIT)
        except (BlockingIOError, InterruptedError):
            chunk = None  # not asked yet
        except OSError:
            conn.close()
            return
        sent = 0
        if chunk == b"\n":  # the plain status, asked at once: most reads end here
            answer = self._encode(PLAIN)
            try:
                sent = conn.send(answer, NOWAIT)
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                conn.close()
                return
            if sent == len(answer):
                self.served += 1
                conn.close()
                return
        client = Client(conn, time.monotonic() + REQUEST_WAIT_S)
        self._clients[client.fd] = client
        if len(self._clients) >= MAX_CLIENTS:
            self._accept_on(False)  # full: the rest wait in the backlog
        if chunk is None:
            self._watch(client, select.EPOLLIN)
        elif chunk == b"\n":  # the rest of the answer once the client reads
            client.request = chunk
            client.out = memoryview(answer)[sent:]
            client.deadline = time.monotonic() + SEND_TIMEOUT_S
            self._watch(client, select.EPOLLOUT)
        else:
            self._took(client, chunk)

    def _poked(self) -> None:
        """Subscribers look for a change now (at most every ``SUBSCRIBE_MIN_GAP_S``)."""
        with contextlib.suppress(OSError):
            self._wake_r.recv(4096)
        now = time.monotonic()
        for client in self._clients.values():
            sub = client.sub
            if sub is not None:
                sub.due = min(sub.due, max(now, sub.sent_at + SUBSCRIBE_MIN_GAP_S))

    def _serve(self, client: Client) -> None:
        """Take the request, answer it, as far as it goes without blocking; then let the
        epoll watch for what it waits for."""
        if client.sub is not None:
            self._serve_subscriber(client)
            return
        if client.kept:
            self._serve_kept(client)
            return
        if client.out is not None:
            self._send(client)
            return
        try:
            chunk = client.sock.recv(MAX_REQUEST, NOWAIT)
        except (BlockingIOError, InterruptedError):
            self._watch(client, select.EPOLLIN)
            return
        except OSError:
            self._drop(client)
            return
        self._took(client, chunk)

    def _took(self, client: Client, chunk: bytes) -> None:
        """``chunk`` of the request came (empty: the end of input): answer once it is in."""
        client.request += chunk
        if chunk and b"\n" not in client.request and len(client.request) <= MAX_REQUEST:
            self._watch(client, select.EPOLLIN)
            return
        self._answer(client)  # a line, the end of input, or too long
        if client.sub is None and not client.kept and client.out is not None:
            self._send(client)  # (a subscriber's first update is on its way; or dropped;
            # a kept connection's answers too)

    def _answer(self, client: Client) -> None:
        request = parse_request(client.request)
        if request.keep:
            self._keep(client)
            return
        period = request.period
        if period is not None and request.error is None:
            if self.subscribers >= MAX_SUBSCRIBERS:
                self._evict_one()
            if self.subscribers >= MAX_SUBSCRIBERS:
                request = Request(
                    error=f"too many subscribers ({MAX_SUBSCRIBERS}), each reading its updates: "
                    "the daemon is full; close one, or read the status once"
                )
            else:
                self.subscribers += 1
                client.sub = Subscription(period, time.monotonic())
                self._update(client, time.monotonic(), None)
                return
        client.out = memoryview(self._encode(request))
        client.deadline = time.monotonic() + SEND_TIMEOUT_S

    # -- kept connections ---------------------------------------------------------------
    def _keep(self, client: Client) -> None:
        """``keep`` came: from now on one answer per request line (those after it in the
        same write too), the first of them at once."""
        if self.kept >= MAX_KEPT:
            self._evict_kept()
        self.kept += 1
        client.kept = True
        client.asked = time.monotonic()
        client.ending = b"\n" not in client.request  # ``keep`` at its end of input, unended
        client.request = client.request.partition(b"\n")[2]
        self._kept_turn(client)

    def _evict_kept(self) -> None:
        """Full, and another asks to keep its connection: the kept one that asked longest
        ago goes (one whose answer is still being sent first); its reader connects again
        when it next asks (daemon/status/reader.py's StatusReader does so on its own)."""
        kept = [c for c in self._clients.values() if c.kept]
        if not kept:
            return
        gone = min(kept, key=lambda c: (c.out is None, c.asked))
        self.kept_evicted += 1
        log.info(
            "status socket %s: %d kept connections, the most there may be: closed the one "
            "that asked longest ago to let a new one in (%d so far)",
            self.path,
            MAX_KEPT,
            self.kept_evicted,
        )
        self._drop(gone)

    def _serve_kept(self, client: Client) -> None:
        """Readable: its next request lines (or its end); writable: the rest of an answer."""
        if client.out is None:
            try:
                chunk = client.sock.recv(MAX_REQUEST, NOWAIT)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self._drop(client)
                return
            if chunk:
                client.request += chunk
            else:
                client.ending = True  # it sent all it will: answer its whole lines, then close
        self._kept_turn(client)

    def _kept_turn(self, client: Client) -> None:
        """Answer the kept client's whole request lines in order, as far as its socket
        takes them without blocking; then let the epoll watch for what it waits for."""
        while True:
            out = client.out
            if out is not None:
                try:
                    sent = client.sock.send(out, NOWAIT)
                except (BlockingIOError, InterruptedError):
                    sent = 0
                except OSError:
                    self._drop(client)
                    return
                if sent < len(out):
                    client.out = out[sent:]
                    self._watch(client, select.EPOLLOUT)
                    return
                client.out = None
                self.served += 1
            request = client.request
            end = request.find(b"\n") + 1
            if not end:
                break
            client.request = request[end:]
            client.out = memoryview(self._kept_answer(request[:end]))
            now = time.monotonic()
            client.asked = now
            client.deadline = now + SEND_TIMEOUT_S
        if client.ending:
            self._drop(client)
            return
        if len(client.request) > MAX_REQUEST:  # no line end in sight: say so, then close
            client.out = memoryview(self._encode(parse_request(client.request)) + b"\n")
            client.request = b""
            client.ending = True
            client.deadline = time.monotonic() + SEND_TIMEOUT_S
            self._kept_turn(client)
            return
        client.deadline = time.monotonic() + KEEP_IDLE_S
        self._watch(client, select.EPOLLIN)

    def _kept_answer(self, line: bytes) -> bytes:
        """The answer to one request line of a kept connection, a line of JSON."""
        return self._encode(kept_request(line)) + b"\n"

    # -- subscribers --------------------------------------------------------------------
    def _evict_one(self) -> None:
        """Full, and a subscriber asks: the oldest subscriber that does not read its updates
        goes, so that one that reads gets in. Not reading: an update still being sent (its
        socket is full), or about two updates or more lying unread in its socket (a reader
        takes each as it comes). A client that subscribes and never reads, however quickly
        it comes back, thus never keeps a monitor out."""
        behind = [
            c
            for c in self._clients.values()
            if c.sub is not None
            and (c.out is not None or unread_bytes(c.sock) > 2 * (c.sub.last_len + 1024))
        ]
        if not behind:
            return
        oldest = min(behind, key=lambda c: c.sub.since if c.sub is not None else 0.0)
        self.evicted += 1
        log.warning(
            "status socket %s: %d subscribers, the most there may be: closed the oldest one "
            "that does not read its updates to let a new one in (%d so far)",
            self.path,
            MAX_SUBSCRIBERS,
            self.evicted,
        )
        self._drop(oldest)

    def _serve_subscriber(self, client: Client) -> None:
        """Readable: the subscriber closed (or says something, which is ignored);
        writable: the rest of its update."""
        try:
            while True:
                chunk = client.sock.recv(4096, NOWAIT)
                if not chunk:
                    self._drop(client)
                    return
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._drop(client)
            return
        if client.out is not None:
            self._send(client)

    def _update(self, client: Client, now: float, built: list[tuple[bytes, bytes]] | None) -> None:
        """Look for a change for subscriber ``client`` (not sending one now): send the
        status when it changed or the heartbeat is due. ``built``: the document of this
        turn, shared by the subscribers due in it (empty: not built yet)."""
        sub = client.sub
        assert sub is not None and client.out is None
        sub.due = now + sub.period
        if built is None:
            built = []
        if not built:
            built.append(self._stream_document())
        key, line = built[0]
        if key == sub.key and now - sub.sent_at < HEARTBEAT_S:
            return
        sub.key, sub.sent_at, sub.last_len = key, now, len(line)
        client.out = memoryview(line)
        client.deadline = now + SEND_TIMEOUT_S
        self._send(client)

    def _stream_document(self) -> tuple[bytes, bytes]:
        """(what decides a change, the line to send) of the status now."""
        try:
            doc = self.status()
        except Exception:
            log.exception("cannot build the status document")
            doc = {"error": "status unavailable, see the log"}
        key = self._stable_encoder.encode(stable_view(doc))
        return key, self._encoded(doc) + b"\n"

    def _encoded(self, doc: dict[str, Any]) -> bytes:
        """``doc`` as JSON; the last one's bytes when it is that document again (a frequent
        reader's, daemon/status/document.py)."""
        sent = self._sent
        if sent is not None and sent[0] is doc:
            return sent[1]
        data = self._encoder.encode(doc)
        self._sent = (doc, data)
        return data

    def _send(self, client: Client) -> None:
        assert client.out is not None
        try:
            sent = client.sock.send(client.out, NOWAIT)
        except (BlockingIOError, InterruptedError):
            self._watch(client, select.EPOLLOUT)
            return
        except OSError:
            self._drop(client)
            return
        client.out = client.out[sent:]
        if client.out:
            self._watch(client, select.EPOLLOUT | (select.EPOLLIN if client.sub is not None else 0))
            return
        self.served += 1
        if client.sub is None:
            self._drop(client)
            return
        client.out = None
        client.deadline = math.inf
        self._watch(client, select.EPOLLIN)

    def _watch(self, client: Client, events: int) -> None:
        if client.events == events:
            return
        if client.events:
            self._ep.modify(client.fd, events)
        else:
            self._ep.register(client.fd, events)
        client.events = events

    def _expire(self, now: float) -> None:
        built: list[tuple[bytes, bytes]] = []
        for client in list(self._clients.values()):
            if client.sub is not None and client.out is None:
                if client.sub.due <= now:
                    self._update(client, now, built)
                continue
            if client.kept:
                if client.deadline <= now:
                    self._drop(client)  # asked nothing for KEEP_IDLE_S, or not reading
                continue
            if client.deadline <= now:
                if client.out is None:
                    self._answer(client)  # asked nothing: the plain status
                    if not client.kept:  # (or ``keep`` without its line end: kept)
                        self._send(client)
                else:
                    self._drop(client)  # not reading its answer
        if not self._accepting and len(self._clients) < MAX_CLIENTS and now >= self._resume_accept:
            self._accept_on(True)

    def _drop(self, client: Client) -> None:
        client.out = None
        if client.sub is not None:
            client.sub = None
            self.subscribers -= 1
        if client.kept:
            client.kept = False
            self.kept -= 1
        if self._clients.get(client.fd) is client:
            del self._clients[client.fd]
        client.events = 0  # its close takes it out of the epoll set (the only descriptor)
        client.sock.close()

    def _encode(self, request: Request) -> bytes:
        if request.error is not None:
            return json.dumps({"error": request.error}).encode()
        if request.period is not None:
            return json.dumps(
                {"error": "a subscription is answered by the server's thread"}
            ).encode()
        try:
            if request.histogram:  # 20,001 bins at most: rare, and not worth keeping
                return json.dumps(self.status(histogram=True), sort_keys=True).encode()
            return self._encoded(self.status())
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
