"""The live monitor's view: a status document drawn with ``rich`` (only this module imports
it; :mod:`motorctl.daemon.status.monitor` is the entry point and says what to install without it).

:func:`render` is pure: a document (and the one before it, for rates) in, a renderable out,
so tests draw a known state into a string. :func:`watch` follows the subscription
(docs/status.md) on a reader thread and redraws on each update and every half period (the
frames' ages move; no update within a period means nothing changed, so frames/s is 0), and
reconnects when the daemon restarts; while the daemon is gone the whole view is marked as
the last state seen (a banner, dimmed, nothing read as live). Off a terminal lines are not
wrapped at 80 columns. Every field is read defensively: an older or newer
daemon, or one without per-motor timing figures, draws what it has.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich import box
from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.styled import Styled
from rich.table import Table
from rich.text import Text

from motorctl.daemon.status.monitor import Ending
from motorctl.daemon.status.reader import StatusError, read_status, subscribe

RECENT_SHOWN = 8
RETRY_S = 1.0
STOP_POLL_S = 0.1  # how often the drawing loop looks whether it is to end (SIGINT, SIGTERM)


@dataclass
class Seen:
    """An update and when this process got it (time.monotonic)."""

    doc: Mapping[str, Any]
    at: float


def _d(value: object) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _l(value: object) -> Sequence[Any]:
    return value if isinstance(value, list) else []


def _num(value: object, fmt: str = "{:,}", none: str = "-") -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return none
    return fmt.format(value)


def _duration(seconds: object) -> str:
    if not isinstance(seconds, int | float):
        return "?"
    s = int(seconds)
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}"


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
    frames = _d(_d(now.doc.get("link")).get("counters")).get("frames")
    frames0 = _d(_d(before.doc.get("link")).get("counters")).get("frames")
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
) -> RenderableType:
    """The whole view of ``doc``; ``rate``: frames/s; ``since_s``: how long ago it came
    (frames' ages grow by it); ``note``: a line on the connection; ``stale``: why no update
    comes any more (the daemon stopped, cannot be reached): the whole view is then marked as
    the last state seen, dimmed, with nothing in it read as live (no "alive", no frames/s)."""
    parts: list[RenderableType] = [_header(doc, stale=bool(stale))]
    parts.append(_motors(doc))
    timing = _timing(doc)
    if timing is not None:
        parts.append(timing)
    parts.append(_steps(doc))
    parts.append(_io(doc))
    parts.append(_link(doc, None if stale else rate))
    trace = _trace(doc)
    if trace is not None:
        parts.append(trace)
    parts.append(_recent(doc, since_s))
    drivers = _drivers(doc)
    if drivers is not None:
        parts.append(drivers)
    view: list[RenderableType] = parts
    if stale:
        banner = Text(
            f"NOT LIVE: {stale}. Everything below is the last state motorctld reported, "
            f"{_ago(since_s)} ago.",
            style="bold white on red",
        )
        view = [banner, Styled(Group(*parts), "dim")]
    if note:
        view.append(Text(note, style="yellow"))
    return Group(*view)


def _ago(seconds: float) -> str:
    return f"{seconds:.1f} s" if seconds < 60 else _duration(seconds)


def _header(doc: Mapping[str, Any], stale: bool = False) -> Text:
    ex = _d(doc.get("executor"))
    text = Text("motorctld", style="bold")
    if stale:
        text.append(" (last seen)", style="bold red")
    text.append(f"  up {_duration(doc.get('uptime_s'))}" + (" then" if stale else ""))
    alive = ex.get("alive")
    text.append("  executor ")
    text.append(f"{ex.get('kind', '?')}", style="bold")
    if ex.get("core"):  # the step core (a daemon before issue 24 does not say)
        text.append(f", {ex.get('core')} core")
    if ex.get("pid"):
        text.append(f" (pid {ex.get('pid')})")
    if alive is False:
        text.append(f" DEAD: {ex.get('reason')}", style="bold red")
    elif alive and stale:
        text.append(" state unknown")
    elif alive:
        text.append(" alive", style="green")
    state = _d(doc.get("state"))
    if state:
        if state.get("ok", True):
            text.append(f"  state file ok ({_num(state.get('writes'))} writes)")
        else:
            text.append(f"  STATE NOT SAVED: {state.get('last_error')}", style="bold red")
    return text


def _motors(doc: Mapping[str, Any]) -> Table:
    table = Table(
        title="motors", title_justify="left", box=box.SIMPLE_HEAD, expand=False, padding=(0, 1)
    )
    for name, justify in (
        ("#", "right"),
        ("name", "left"),
        ("state", "left"),
        ("position", "right"),
        ("speed step/s", "right"),
        ("queued", "right"),
        ("waypoints", "right"),
        ("fault", "left"),
    ):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for m in _l(doc.get("motors")):
        m = _d(m)
        state = str(m.get("state", "?"))
        style = {"idle": "", "fault": "bold red"}.get(state, "bold green")
        fault = m.get("fault")
        fault_text = Text(str(fault), style="red") if fault else Text("")
        if m.get("position_lost"):
            fault_text.append(
                " (position lost: home it)" if fault else "position lost: home it", style="yellow"
            )
        table.add_row(
            Text(str(m.get("index", "?"))),
            Text(str(m.get("name", ""))),
            Text(state, style=style),
            Text(_num(m.get("position"))),
            Text(_num(m.get("speed"), "{:,.0f}")),
            Text(_num(m.get("queued"))),
            Text(_num(m.get("waypoints"))),
            fault_text,
        )
    return table


def _timing(doc: Mapping[str, Any]) -> Table | None:
    """Per-motor step timing and faults by cause (issue 15), when the daemon reports them."""
    motors = [_d(m) for m in _l(doc.get("motors"))]
    if not any("timing" in m or "faults" in m for m in motors):
        return None
    table = Table(
        title="step timing per motor", title_justify="left", box=box.SIMPLE_HEAD, padding=(0, 1)
    )
    for name in (
        "#",
        "late absorbed",
        "slid ms",
        "worst late us",
        "worst lag fs",
        "lag limit fs",
        "microsteps",
        "lag faults",
        "faults by cause",
    ):
        table.add_column(name, justify="left" if name == "faults by cause" else "right")
    for m in motors:
        t = _d(m.get("timing"))
        faults = (
            ", ".join(f"{cause} {count}" for cause, count in sorted(_d(m.get("faults")).items()))
            or "none"
        )
        table.add_row(
            Text(str(m.get("index", "?"))),
            Text(_num(t.get("late_absorbed"))),
            Text(_num(t.get("slid_ms"), "{:,.1f}")),
            Text(_num(t.get("worst_late_us"), "{:,.0f}")),
            Text(_num(t.get("worst_lag_full_steps"), "{:,.2f}")),
            Text(_num(t.get("max_lag_full_steps"), "{:,.2f}")),
            Text(_num(t.get("microsteps"))),
            Text(_num(t.get("lag_faults"))),
            Text(faults),
        )
    return table


def _steps(doc: Mapping[str, Any]) -> Text:
    s = _d(doc.get("steps"))
    text = Text("step edges ", style="bold")
    text.append(_num(s.get("steps")))
    text.append(
        f"  lateness p50 {_num(s.get('p50_us'), '{:.0f}')}"
        f" p99 {_num(s.get('p99_us'), '{:.0f}')}"
        f" p99.9 {_num(s.get('p999_us'), '{:.0f}')}"
        f" max {_num(s.get('max_us'), '{:.0f}')} us"
    )
    late = s.get("late")
    text.append(f"  late (>{_num(s.get('late_threshold_us'), '{:.0f}')} us) ")
    text.append(_num(late), style="yellow" if late else "")
    for key, label in (("timing_lost", "timing lost"), ("io_errors", "io errors")):
        value = s.get(key)
        text.append(f"  {label} ")
        text.append(_num(value), style="bold red" if value else "")
    # planned segments a re-plan or stop replaced before they ran: normal, no alarm
    text.append(f"  segments discarded {_num(s.get('segments_discarded'))}")
    stops = _d(doc.get("hard_stops"))
    if stops:
        text.append(
            f"\nhard stops confirmed {_num(stops.get('confirmed'))}"
            f" timed out {_num(stops.get('timed_out'))}"
            f"  wait p99 {_num(stops.get('wait_p99_us'), '{:.0f}')} us"
        )
    clamped = _d(doc.get("clamped"))
    if clamped:
        text.append("  clamped " + ", ".join(f"{k} {v}" for k, v in sorted(clamped.items())))
    return text


def _io(doc: Mapping[str, Any]) -> Text:
    text = Text("pins ", style="bold")
    pins = [_d(p) for p in _l(doc.get("pins"))]
    if not pins:
        text.append("none configured" if "pins" in doc else "not reported")
    for i, p in enumerate(pins):
        if i:
            text.append("  ")
        level = p.get("level")
        word = "?" if level is None else ("H" if level else "L")
        text.append(f"{p.get('number')}:{'out' if p.get('output') else 'in'} ")
        text.append(word, style="bold green" if level else "")
    text.append("\nDC motor ", style="bold")
    dc = doc.get("dc")
    if isinstance(dc, Mapping):
        text.append(str(dc.get("state", "?")), style="bold green" if dc.get("running") else "")
        if dc.get("running"):
            text.append(f", {_num(dc.get('left_s'), '{:.1f}')} s left")
    else:
        text.append("none configured" if "dc" in doc else "not reported")
    return text


def _link(doc: Mapping[str, Any], rate: float | None) -> Text:
    link = _d(doc.get("link"))
    text = Text("link ", style="bold")
    if not link:
        text.append("not serving")
        return text
    c = _d(link.get("counters"))
    text.append(f"host port {link.get('peer', '?')}  frames {_num(c.get('frames'))}")
    if rate is not None:  # none from a single document (--once) or a stale view
        text.append(f" ({rate:,.1f}/s)")
    bad = {
        k.removesuffix("_errors"): v
        for k, v in c.items()
        if k.endswith("_errors") and k not in ("link_errors", "internal_errors") and v
    }
    text.append("  bad frames ")
    text.append(
        ", ".join(f"{k} {v}" for k, v in sorted(bad.items())) or "0", style="yellow" if bad else ""
    )
    sent = {k.removeprefix("sent_"): v for k, v in c.items() if k.startswith("sent_") and v}
    text.append("  errors sent ")
    text.append(
        ", ".join(f"{k}x{v}" for k, v in sorted(sent.items())) or "none",
        style="yellow" if sent else "",
    )
    text.append(
        f"\n     held {_num(link.get('held'))} (max {_num(c.get('held_max'))})"
        f"  waiting {'yes' if link.get('waiting') else 'no'}"
        f"  gap discards {_num(c.get('gap_discards'))}"
    )
    p = _d(link.get("processing"))
    text.append(
        f"  processing p50 {_num(p.get('p50_us'), '{:.0f}')}"
        f" p99 {_num(p.get('p99_us'), '{:.0f}')} max {_num(p.get('max_us'), '{:.0f}')} us"
    )
    for key in ("link_errors", "internal_errors", "responses_dropped"):
        if c.get(key):
            text.append(f"  {key.replace('_', ' ')} {c[key]}", style="bold red")
    return text


def _trace(doc: Mapping[str, Any]) -> Text | None:
    """The link's trace (motorctld --trace), when it records one."""
    t = _d(doc.get("trace"))
    if not t:
        return None
    text = Text("trace ", style="bold")
    text.append(f"{t.get('file', '?')}")
    if t.get("part"):
        text.append(f" (part {t.get('part')} of session {t.get('session', '?')})")
    text.append(f"  runs {_num(t.get('runs'))}  written {_num(t.get('bytes_written'))} bytes")
    for key, label in (
        ("dropped_runs", "runs left out"),
        ("write_errors", "write errors"),
        ("lost_bytes", "bytes lost"),
    ):
        value = t.get(key)
        text.append(f"  {label} ")
        text.append(_num(value), style="bold red" if value else "")
    return text


def _recent(doc: Mapping[str, Any], since_s: float) -> Table:
    table = Table(title="last frames", title_justify="left", box=box.SIMPLE_HEAD, padding=(0, 1))
    table.add_column("age s", justify="right", no_wrap=True)
    table.add_column("frame", no_wrap=True)
    table.add_column("command")
    table.add_column("answer", no_wrap=True)
    now = doc.get("monotonic_s")
    recent = [_d(r) for r in _l(_d(doc.get("link")).get("recent"))]
    for r in reversed(recent[-RECENT_SHOWN:]):
        at = r.get("at_s")
        age = (
            (now - at + since_s)
            if isinstance(now, int | float) and isinstance(at, int | float)
            else None
        )
        result = r.get("result")
        style = "red" if isinstance(result, str) and result.startswith("E") else ""
        table.add_row(
            Text(_num(age, "{:.1f}", "?")),
            Text(str(r.get("frame", ""))),
            Text(str(r.get("command", ""))),
            Text("(owed)" if result is None else str(result), style=style),
        )
    return table


def _drivers(doc: Mapping[str, Any]) -> Text | None:
    drivers = [_d(d) for d in _l(doc.get("drivers"))]
    if not drivers:
        return None
    text = Text("drivers", style="bold")
    for d in drivers:
        text.append(
            f"\n  {d.get('chip')} {d.get('device')}: polls {_num(d.get('polls'))}"
            f"  spi errors {_num(d.get('spi_errors'))}  "
            + (f"DRV_STATUS {d.get('drv_status')}" if "drv_status" in d else "")
            + (f"#{d.get('chain_position')} STATUS {d.get('status')}" if "status" in d else "")
        )
        faults = _d(d.get("fault_counts"))
        if faults:
            text.append(
                "  faults " + ", ".join(f"{k} {v}" for k, v in sorted(faults.items())), style="red"
            )
    return text


# -- the terminal ---------------------------------------------------------------------------
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
        print_error(console, f"no daemon status at {path}: {exc}")
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


def watch(
    path: Path,
    period_ms: int,
    console: Console | None = None,
    ending: Ending | None = None,
) -> int:
    """Refresh in the terminal until ``ending`` is requested (SIGINT, SIGTERM: exit 0; it
    is looked at every ``STOP_POLL_S``; it is told while the monitor's screen is on). Not
    on a terminal: one drawing per update, one after another. Once the daemon is gone (or
    cannot be reached), the whole view is marked as the last state seen until updates come
    again."""
    console = _console(console)
    ending = ending or Ending()
    period_s = max(20, min(60_000, period_ms)) / 1000.0
    redraw_s = max(0.1, period_s / 2)  # a terminal's "updated N s ago" without an update
    updates: queue.Queue[Seen | str] = queue.Queue()
    reader_stop = threading.Event()
    reader = threading.Thread(
        target=_follow,
        args=(path, period_s, updates, reader_stop),
        name="motorctl-monitor",
        daemon=True,
    )
    reader.start()
    last: Seen | None = None
    before: Seen | None = None
    stale = ""
    live = (
        Live(console=console, screen=console.is_terminal, auto_refresh=False, transient=False)
        if console.is_terminal
        else None
    )
    redraw_at = time.monotonic() + redraw_s
    try:
        with live if live is not None else contextlib.nullcontext():
            ending.screen = live is not None
            while not ending.requested:
                try:
                    item = updates.get(timeout=STOP_POLL_S)
                except queue.Empty:
                    if live is None or time.monotonic() < redraw_at:
                        continue
                    item = None
                redraw_at = time.monotonic() + redraw_s
                if isinstance(item, Seen):
                    before, last, stale = last, item, ""
                elif isinstance(item, str):
                    stale, before = item, None
                view = _view(last, before, stale, period_s, path)
                if live is not None:
                    live.update(view, refresh=True)
                elif item is not None:
                    console.print(view)
                    console.print(RULE)
    finally:
        ending.screen = False
        reader_stop.set()
    return 0


def _view(
    last: Seen | None, before: Seen | None, stale: str, period_s: float, path: Path
) -> RenderableType:
    if last is None:
        return Text(
            f"{stale}; retrying every {RETRY_S:.0f} s" if stale else f"connecting to {path} ...",
            style="yellow",
        )
    now = time.monotonic()
    if stale:
        return render(
            last.doc,
            since_s=now - last.at,
            note=f"retrying every {RETRY_S:.0f} s; the view comes back with the daemon; "
            "Ctrl-C quits",
            stale=stale,
        )
    rate = frames_per_second(last, before, now, period_s)
    footer = (
        f"updated {now - last.at:.1f} s ago; the daemon sends a change as it "
        f"comes, looking every {period_s * 1000:.0f} ms; Ctrl-C quits"
    )
    return render(last.doc, rate, since_s=now - last.at, note=footer)
