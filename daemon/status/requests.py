"""What the status socket's clients ask, and what its server keeps of each connection.

A request is one line of words, ``\n``-terminated (docs/status.md): empty for the status,
``histogram`` for the status with the full step-lateness histogram (``steps.histogram_us``,
up to 20,001 bins: built and encoded only when asked), ``subscribe [PERIOD_MS]`` for a
stream of updates (the status at once, then again whenever it changed, looked at every
PERIOD_MS, default ``SUBSCRIBE_PERIOD_S``, at least every ``HEARTBEAT_S`` even when nothing
changed), ``keep`` for a kept connection (``keep`` itself is not answered; each request
line after it, empty or ``histogram``, gets one document on one line, in order, until the
client closes: a frequent reader pays the accept and the close once).
:func:`parse_request` gives a line's meaning and :func:`stable_view` what of a document
decides a subscriber's update: both pure. :class:`Client` and :class:`Subscription` are
what daemon/status/server.py keeps of each connection; daemon/status/reader.py follows the
same protocol (``HEARTBEAT_S``).

Threads: the status server's thread owns every Client and Subscription; the rest holds no
state.
"""

from __future__ import annotations

import math
import socket
from typing import Any

MAX_REQUEST = 256
REQUESTS = ("histogram", "subscribe [PERIOD_MS]", "keep")
KEPT_REQUESTS = ("an empty line", "histogram")
SUBSCRIBE_PERIOD_S = 0.25
PERIOD_MS_RANGE = (20, 60_000)
HEARTBEAT_S = 5.0
#: fields that change at every look without anything happening: not a reason for an update
VOLATILE = ("monotonic_s", "uptime_s", "unix_s")
VOLATILE_STEPS = ("progress",)


class Subscription:
    """A subscriber's stream: when it is looked at next and what it was sent last."""

    __slots__ = ("due", "key", "last_len", "period", "sent_at", "since")

    def __init__(self, period: float, since: float) -> None:
        self.period = period
        self.since = since  # when it subscribed: the oldest is evicted first
        self.due = 0.0  # when to look for a change next
        self.key: bytes | None = None  # the last update sent, volatile fields left out
        self.sent_at = -math.inf
        self.last_len = 0  # the last update's length


class Client:
    """A connection to the status socket as the server keeps it."""

    __slots__ = (
        "asked",
        "deadline",
        "ending",
        "events",
        "fd",
        "kept",
        "out",
        "request",
        "sock",
        "sub",
    )

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.request = b""
        self.out: memoryview | None = None  # the answer, once the request is in
        self.deadline = deadline
        self.events = 0  # what the epoll watches for it (0: not registered)
        self.sub: Subscription | None = None  # a subscriber's stream
        self.kept = False  # a kept connection: one answer per request line
        self.asked = 0.0  # a kept one's last request (the one that asked longest ago goes first)
        self.ending = False  # a kept one: closed once the answers to its whole lines are sent


class Request:
    """A parsed request line: what to answer, or the error to answer with."""

    __slots__ = ("error", "histogram", "keep", "period")

    def __init__(
        self,
        histogram: bool = False,
        period: float | None = None,
        error: str | None = None,
        keep: bool = False,
    ) -> None:
        self.histogram = histogram
        self.period = period  # a subscription's period in seconds; None: one document
        self.error = error
        self.keep = keep  # keep the connection: one document per request line after this


#: the plain status's request (an empty line): its meaning, not parsed again at each read
#: (never changed: a request is read, not written, once parsed)
PLAIN = Request()


def parse_request(request: bytes) -> Request:
    """The request line's meaning (docs/status.md)."""
    if request == b"\n":
        return PLAIN
    if len(request) > MAX_REQUEST:
        return Request(
            error=f"unknown status request: a request line too long; known: {', '.join(REQUESTS)}"
        )
    words = request.split(b"\n", 1)[0].decode("ascii", "replace").split()
    if words[:1] == ["subscribe"]:
        lo, hi = PERIOD_MS_RANGE
        if len(words) == 1:
            return Request(period=SUBSCRIBE_PERIOD_S)
        if len(words) == 2 and words[1].isdigit() and lo <= int(words[1]) <= hi:
            return Request(period=int(words[1]) / 1000.0)
        return Request(
            error=f"subscribe: PERIOD_MS must be a whole number of milliseconds "
            f"from {lo} to {hi}, got {' '.join(words[1:])!r}"
        )
    if words[:1] == ["keep"]:
        if len(words) == 1:
            return Request(keep=True)
        return Request(error=f"keep takes no words, got {' '.join(words[1:])!r}")
    unknown = [w for w in words if w != "histogram"]
    if unknown:
        return Request(
            error=f"unknown status request: {' '.join(unknown)}; known: {', '.join(REQUESTS)}"
        )
    return Request(histogram="histogram" in words)


def stable_view(doc: dict[str, Any]) -> dict[str, Any]:
    """``doc`` without the fields that change at every look (the clock, the executor's
    turns): what decides whether a subscriber gets an update."""
    view = {k: v for k, v in doc.items() if k not in VOLATILE}
    steps = view.get("steps")
    if isinstance(steps, dict):
        view["steps"] = {k: v for k, v in steps.items() if k not in VOLATILE_STEPS}
    return view


def kept_request(line: bytes) -> Request:
    """The meaning of a request line on a kept connection: a subscription or another
    ``keep`` there is an error (it is answered with an error document, and the connection
    stays)."""
    request = parse_request(line)
    if request.error is None and (request.keep or request.period is not None):
        return Request(
            error=f"on a kept connection ask for {' or '.join(KEPT_REQUESTS)}; "
            "subscribe on a connection of its own"
        )
    return request
