"""The live monitor's view: a status document drawn for a terminal or a log, and when to
draw it. :mod:`motorctl.daemon.status.monitor` is the entry point and says what to install
without ``rich``; this module and the ones it draws with (monitor_layout.py: styled lines
and tables; monitor_parts.py: each part of a document; monitor_screen.py: the terminal)
are the only ones that import it.

:func:`render` is pure: a document (and the one before it, for rates) in, a
:class:`~motorctl.daemon.status.monitor_layout.View` out, so tests draw a known state into a
string. rich prints a view (``--once``, off a terminal, the tests); on a terminal
:class:`~motorctl.daemon.status.monitor_screen.Screen` writes only the lines that changed.

:func:`watch` follows the subscription (docs/status.md) on a reader thread and draws again
only when what it shows changes (:class:`Watched`): an update (the daemon sends one only
when something changed), the daemon gone or back, the frames/s falling to 0, or another
whole second since the last update (the ages shown move in whole seconds; at rest that is
one drawing a second of the few lines that changed). It reconnects when the daemon
restarts; while the daemon is gone the whole view is marked as the last state seen (a
banner, dimmed, nothing read as live). Off a terminal lines are not wrapped at 80 columns.

Threads: the caller's thread draws and owns every object here (:class:`Watched`, the
screen, the views); :func:`_follow` runs on the reader thread and hands updates over
through a queue.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.text import Text

from motorctl.daemon.status.monitor import Ending
from motorctl.daemon.status.monitor_layout import Grid, Para, View
from motorctl.daemon.status.monitor_parts import (
    RECENT_SHOWN,
    drivers_para,
    header_para,
    io_para,
    link_para,
    motors_grid,
    recent_grid,
    steps_para,
    timing_grid,
    trace_para,
)
from motorctl.daemon.status.monitor_screen import Screen
from motorctl.daemon.status.reader import StatusError, read_status, subscribe, unreachable
from motorctl.daemon.status.summary import as_list, as_map, duration

RETRY_S = 1.0
STOP_POLL_S = 0.1  # how often the drawing loop looks whether it is to end (SIGINT, SIGTERM)


@dataclass
class Seen:
    """An update and when this process got it (time.monotonic)."""

    doc: Mapping[str, Any]
    at: float


def frames_per_second(
    now: Seen, before: Seen | None, local_now: float, period_s: float
) -> float | None:
    """Frames per second between the last two updates; 0 once no update came for longer
    than a period and a half (an update would have come had a frame arrived); None with a
    single update."""
    if before is None:
        return None
    if local_now - now.at > 1.5 * period_s + 0.5:
        return 0.0
    frames = as_map(as_map(now.doc.get("link")).get("counters")).get("frames")
    frames0 = as_map(as_map(before.doc.get("link")).get("counters")).get("frames")
    t, t0 = now.doc.get("monotonic_s"), before.doc.get("monotonic_s")
    if not all(isinstance(v, int | float) for v in (frames, frames0, t, t0)):
        return None
    assert isinstance(frames, int | float) and isinstance(frames0, int | float)
    assert isinstance(t, int | float) and isinstance(t0, int | float)
    return (frames - frames0) / (t - t0) if t > t0 else None


def render(
    doc: Mapping[str, Any],
    rate: float | None = None,
    since_s: float = 0.0,
    note: str = "",
    stale: str = "",
    before: View | None = None,
) -> View:
    """The whole view of ``doc``; ``rate``: frames/s; ``since_s``: how long ago it came
    (frames' ages grow by it); ``note``: a line on the connection; ``stale``: why no update
    comes any more (the daemon stopped, cannot be reached): the whole view is then marked as
    the last state seen, dimmed, with nothing in it read as live (no "alive", no frames/s).

    ``before``: the view drawn last, if any: each of its parts built from the same inputs
    (the parts of the document it reads, compared by value) is taken over as it is, laid
    out already; the view is the same as without it."""
    rate = None if stale else rate
    motors = [as_map(m) for m in as_list(doc.get("motors"))]
    recent = as_list(as_map(doc.get("link")).get("recent"))[-RECENT_SHOWN:]
    inputs: dict[str, tuple[object, Callable[[], Para | Grid | None]]] = {
        "header": (
            (doc.get("executor"), doc.get("uptime_s"), doc.get("state"), bool(stale)),
            lambda: header_para(doc, stale=bool(stale)),
        ),
        "motors": (doc.get("motors"), lambda: motors_grid(doc)),
        "timing": (
            [
                (m.get("index"), m.get("timing"), m.get("faults"), "timing" in m, "faults" in m)
                for m in motors
            ],
            lambda: timing_grid(doc),
        ),
        "steps": (
            (doc.get("steps"), doc.get("hard_stops"), doc.get("clamped")),
            lambda: steps_para(doc),
        ),
        "io": ((doc.get("pins"), doc.get("dc"), "pins" in doc, "dc" in doc), lambda: io_para(doc)),
        "link": ((doc.get("link"), rate), lambda: link_para(doc, rate)),
        "trace": (doc.get("trace"), lambda: trace_para(doc)),
        "recent": ((recent, doc.get("monotonic_s"), since_s), lambda: recent_grid(doc, since_s)),
        "drivers": (doc.get("drivers"), lambda: drivers_para(doc)),
    }
    built: dict[str, tuple[object, Para | Grid | None]] = {}
    for name, (key, build) in inputs.items():
        old = before.parts.get(name) if before is not None else None
        built[name] = old if old is not None and old[0] == key else (key, build())
    parts = [part for _, part in built.values() if part is not None]
    view = View(parts, parts=built)
    if stale:
        banner = Para(
            f"NOT LIVE: {stale}. Everything below is the last state motorctld reported, "
            f"{_ago(since_s)} ago.",
            style="bold white on red",
        )
        view = View(parts, dim=True, banner=banner, parts=built)
    if note:
        view.notes.append(Para(note, style="yellow"))
    return view


def _ago(seconds: float) -> str:
    return f"{seconds:.1f} s" if seconds < 60 else duration(seconds)


# -- drawing: once, or watching ---------------------------------------------------------------
NO_WRAP = 1000  # columns off a terminal: each line as long as it is (COLUMNS still wins)
RULE = "-" * 72  # between drawings off a terminal


def _console(console: Console | None) -> Console:
    """The console to draw on: a terminal's width on a terminal; off one (a pipe, a log)
    lines are not wrapped at rich's 80 columns unless COLUMNS says a width."""
    if console is not None:
        return console
    console = Console()
    if not console.is_terminal and "COLUMNS" not in os.environ:
        console.width = NO_WRAP
    return console


def once(path: Path, console: Console | None = None) -> int:
    """Draw the status once (``motorctl monitor --once``): for scripts and logs."""
    console = _console(console)
    try:
        doc = read_status(path)
    except (OSError, ValueError) as exc:
        print_error(console, f"no daemon status at {path}: {unreachable(path, exc)}")
        return 1
    if set(doc) == {"error"}:
        print_error(console, f"{path}: {doc['error']}")
        return 1
    console.print(render(doc))
    return 0


def print_error(console: Console, message: str) -> None:
    Console(stderr=True, width=console.width).print(Text(f"error: {message}"))


def _follow(
    path: Path, period_s: float, updates: queue.Queue[Seen | str], stop: threading.Event
) -> None:
    """Reader thread: the subscription's updates into ``updates``; a string says why none
    come (then it tries again every RETRY_S): every such string means the view is stale."""
    while not stop.is_set():
        try:
            stream = subscribe(path, period_s)
            try:
                for doc in stream:
                    updates.put(Seen(doc, time.monotonic()))
                    if stop.is_set():
                        return
                updates.put(f"motorctld at {path} stopped")
            finally:
                stream.close()
        except StatusError as exc:  # an error document: a daemon is there, and says why not
            updates.put(f"motorctld at {path} is running but refused the subscription: {exc}")
        except TimeoutError as exc:  # names the path: silent for too long, or every slot busy
            updates.put(f"motorctld does not answer: {exc}")
        except OSError as exc:
            updates.put(f"no motorctld at {path} ({exc.strerror or exc})")
        except ValueError as exc:
            updates.put(f"motorctld at {path} sent something that is not a status ({exc})")
        stop.wait(RETRY_S)


class Watched:
    """What the monitor shows, from the updates taken so far (:meth:`take`), and what a
    drawing at a moment depends on (:meth:`shown`): a drawing is due only when that
    changes. Ages are shown in whole seconds since the last update, so at rest (no update)
    the view changes once a second, not at every look. ``now`` is given to every method (a
    clock reading, time.monotonic's as :class:`Seen`'s): tests choose it."""

    def __init__(self, period_s: float, path: Path) -> None:
        self.period_s = period_s
        self.path = path
        self.last: Seen | None = None
        self.before: Seen | None = None
        self.stale = ""
        self.taken = 0
        self.drawn: View | None = None  # the last view built: its unchanged parts are reused

    def take(self, item: Seen | str) -> None:
        """An update, or why none come (the view is then stale until the next update)."""
        self.taken += 1
        if isinstance(item, Seen):
            self.before, self.last, self.stale = self.last, item, ""
        else:
            self.stale, self.before = item, None

    def since(self, now: float) -> float:
        """Whole seconds since the last update: what the footer and the ages show."""
        return float(int(max(0.0, now - self.last.at))) if self.last is not None else 0.0

    def rate(self, now: float) -> float | None:
        """Frames per second (None while stale: nothing is read as live)."""
        if self.last is None or self.stale:
            return None
        return frames_per_second(self.last, self.before, now, self.period_s)

    def shown(self, now: float) -> tuple[object, ...]:
        """What a drawing at ``now`` depends on: the same at two moments, the same view."""
        return (self.taken, self.since(now), self.rate(now))

    def view(self, now: float) -> View:
        if self.last is None:
            return View(
                [
                    Para(
                        f"{self.stale}; retrying every {RETRY_S:.0f} s"
                        if self.stale
                        else f"connecting to {self.path} ...",
                        style="yellow",
                    )
                ]
            )
        since = self.since(now)
        if self.stale:
            self.drawn = render(
                self.last.doc,
                since_s=since,
                note=f"retrying every {RETRY_S:.0f} s; the view comes back with the daemon; "
                "Ctrl-C quits",
                stale=self.stale,
                before=self.drawn,
            )
        else:
            footer = (
                f"updated {since:.0f} s ago; the daemon sends a change as it comes, looking "
                f"every {self.period_s * 1000:.0f} ms; Ctrl-C quits"
            )
            self.drawn = render(
                self.last.doc, self.rate(now), since_s=since, note=footer, before=self.drawn
            )
        return self.drawn


def watch(
    path: Path,
    period_ms: int,
    console: Console | None = None,
    ending: Ending | None = None,
) -> int:
    """Refresh in the terminal until ``ending`` is requested (SIGINT, SIGTERM: exit 0; it
    is looked at every ``STOP_POLL_S``; it is told while the monitor's screen is on): a
    drawing whenever what is shown changes (:class:`Watched`), of the lines that changed
    (:class:`Screen`). Not on a terminal: one drawing per update, one after another. Once
    the daemon is gone (or cannot be reached), the whole view is marked as the last state
    seen until updates come again."""
    console = _console(console)
    ending = ending or Ending()
    period_s = max(20, min(60_000, period_ms)) / 1000.0
    updates: queue.Queue[Seen | str] = queue.Queue()
    reader_stop = threading.Event()
    reader = threading.Thread(
        target=_follow,
        args=(path, period_s, updates, reader_stop),
        name="motorctl-monitor",
        daemon=True,
    )
    reader.start()
    watched = Watched(period_s, path)
    screen = Screen(console) if console.is_terminal else None
    drawn: tuple[object, ...] | None = None
    try:
        with screen if screen is not None else contextlib.nullcontext():
            ending.screen = screen is not None
            while not ending.requested:
                try:
                    item: Seen | str | None = updates.get(timeout=STOP_POLL_S)
                except queue.Empty:
                    item = None
                if item is not None:
                    watched.take(item)
                now = time.monotonic()
                if screen is None:
                    if item is not None:
                        console.print(watched.view(now))
                        console.print(RULE)
                    continue
                size = console.size
                shown = (watched.shown(now), size.width, size.height)
                if shown != drawn:
                    drawn = shown
                    screen.draw(watched.view(now), (size.width, size.height))
    finally:
        ending.screen = False
        reader_stop.set()
    return 0
