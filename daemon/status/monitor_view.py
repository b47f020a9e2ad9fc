"""The live monitor's view: a status document drawn as lines of styled text (``rich``
prints them and knows the terminal; only this module imports it:
:mod:`motorctl.daemon.status.monitor` is the entry point and says what to install without it).

:func:`render` is pure: a document (and the one before it, for rates) in, a :class:`View`
out, so tests draw a known state into a string. The view is laid out here, for a width, as
lines of (text, style) spans (:meth:`View.lines`): rich prints those lines (``--once``, off
a terminal, the tests), and on a terminal :class:`Screen` writes only the lines that changed
since its last drawing. One layout, two ways out; rich's own tables and its live display
cost some 10-20 ms of CPU a drawing, which at 10 drawings a second was a fifth of a CPU.

:func:`watch` follows the subscription (docs/status.md) on a reader thread and draws again
only when what it shows changes (:class:`Watched`): an update (the daemon sends one only
when something changed), the daemon gone or back, the frames/s falling to 0, or another
whole second since the last update (the ages shown move in whole seconds; at rest that is
one drawing a second of the few lines that changed). It reconnects when the daemon
restarts; while the daemon is gone the whole view is marked as the last state seen (a
banner, dimmed, nothing read as live). Off a terminal lines are not wrapped at 80 columns.
Every field is read defensively: an older or newer daemon, or one without per-motor timing
figures, draws what it has.

Threads: the caller's thread draws and owns every object here (:class:`Watched`,
:class:`Screen`, the views); :func:`_follow` runs on the reader thread and hands updates
over through a queue.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.cells import cell_len
from rich.console import COLOR_SYSTEMS, Console, ConsoleOptions
from rich.segment import Segment
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


# -- the layout: lines of (text, style) spans ------------------------------------------------
Span = tuple[str, str]  # text, a rich style definition ("" plain)
Line = tuple[Span, ...]


def _style(base: str, style: str) -> str:
    return f"{base} {style}" if base and style else base or style


def _cells(text: str) -> int:
    """The columns ``text`` takes on a terminal."""
    return len(text) if text.isascii() else cell_len(text)


def _width(line: Line) -> int:
    text = line[0][0] if len(line) == 1 else "".join(text for text, _ in line)
    return len(text) if text.isascii() else cell_len(text)


def _fit(text: str, start: int, width: int) -> int:
    """Where the part of ``text`` from ``start`` that fits in ``width`` cells ends."""
    if text.isascii():
        return min(len(text), start + width)
    end, used = start, 0
    while end < len(text) and used + _cells(text[end]) <= width:
        used += _cells(text[end])
        end += 1
    return end


def _slice(line: Line, start: int, end: int) -> Line:
    """The characters ``start`` to ``end`` of ``line``, each in its style."""
    out: list[Span] = []
    at = 0
    for text, style in line:
        after = at + len(text)
        if after > start and at < end:
            out.append((text[max(0, start - at) : end - at], style))
        at = after
    return tuple(out)


def _wrap(line: Line, width: int) -> list[Line]:
    """``line`` in lines of at most ``width`` cells, broken at a space where there is one
    (the space dropped), else within a word (as rich wraps a text)."""
    text = "".join(part for part, _ in line)
    if _cells(text) <= width:
        return [line]
    out: list[Line] = []
    start = 0
    while start < len(text):
        end = _fit(text, start, width)
        if end < len(text):
            space = text.rfind(" ", start + 1, end + 1)
            if space > start:
                end = space
        end = max(end, start + 1)
        out.append(_slice(line, start, end))
        start = end
        while start < len(text) and text[start] == " ":
            start += 1
    return out


class Para:
    """Styled text of one or more lines (``\\n`` in it breaks a line), as rich's ``Text``
    with a base style: ``style`` applies to the whole text, an appended span's own style
    over it."""

    __slots__ = ("_laid", "base", "spans")

    def __init__(self, text: str = "", style: str = "") -> None:
        self.base = style
        self.spans: list[list[Span]] = [[]]
        self._laid: tuple[int, list[Line]] | None = None  # its lines at a width
        if text:
            self.append(text)

    def append(self, text: str, style: str = "") -> None:
        style = _style(self.base, style)
        if "\n" not in text:  # most: no new line
            line = self.spans[-1]
            if line and line[-1][1] == style:  # one span for text of one style
                line[-1] = (line[-1][0] + text, style)
            elif text:
                line.append((text, style))
            return
        for i, part in enumerate(text.split("\n")):
            if i:
                self.spans.append([])
            if part:
                self.spans[-1].append((part, style))

    def lines(self, width: int | None = None) -> list[Line]:
        """Its lines, wrapped at ``width`` cells (None: as they are)."""
        if width is None:
            return [tuple(spans) for spans in self.spans]
        if self._laid is None or self._laid[0] != width:
            lines = [wrapped for spans in self.spans for wrapped in _wrap(tuple(spans), width)]
            self._laid = (width, lines)
        return self._laid[1]


@dataclass
class _Column:
    name: str
    justify: str
    no_wrap: bool


class Grid:
    """A table drawn as rich's ``box.SIMPLE_HEAD`` table with a cell padding of one: its
    title (left, italic), the header (bold) ruled off, the rows, a blank line; each column
    as wide as its widest cell. Too wide for the width: the widest columns that may wrap
    are narrowed and their cells wrapped (what is left over is cut at the edge)."""

    __slots__ = ("_laid", "columns", "rows", "title")

    def __init__(self, title: str) -> None:
        self.title = title
        self.columns: list[_Column] = []
        self.rows: list[list[Para | str]] = []
        self._laid: tuple[int, list[Line]] | None = None  # its lines at a width

    def add_column(self, name: str, justify: str = "left", no_wrap: bool = False) -> None:
        self.columns.append(_Column(name, justify, no_wrap))

    def add_row(self, *cells: Para | str) -> None:
        """A row of cells: styled text, or plain text (most cells)."""
        self.rows.append(list(cells))

    def lines(self, width: int) -> list[Line]:
        """Its lines for ``width`` cells (none wider)."""
        if self._laid is None or self._laid[0] != width:
            self._laid = (width, self._lay(width))
        return self._laid[1]

    def _lay(self, width: int) -> list[Line]:
        cols = self.columns
        # each cell's lines as they are, and its width: the columns' natural widths
        cells: list[list[tuple[Line, ...]]] = [[(((c.name, "bold"),),) for c in cols]]
        used = [[_cells(c.name) for c in cols]]
        for given in self.rows:
            cells.append([])
            used.append([])
            for cell in given:
                if isinstance(cell, str) and "\n" not in cell:  # most cells: plain, one line
                    cells[-1].append((((cell, ""),),))
                    used[-1].append(len(cell) if cell.isascii() else cell_len(cell))
                else:
                    lines = tuple(map(tuple, (Para(cell) if isinstance(cell, str) else cell).spans))
                    cells[-1].append(lines)
                    used[-1].append(max(map(_width, lines)))
        widths = list(map(max, zip(*used, strict=True)))
        inner = sum(widths) + 3 * len(cols) - 1  # each cell padded by 1, a space between
        excess = inner + 2 - width
        while excess > 0:
            wrappable = [i for i, c in enumerate(cols) if not c.no_wrap and widths[i] > 4]
            if not wrappable:
                break
            widest = max(wrappable, key=lambda i: widths[i])
            second = max((widths[i] for i in wrappable if i != widest), default=4)
            cut = min(excess, widths[widest] - max(4, min(second, widths[widest] - 1)))
            widths[widest] -= cut
            excess -= cut
        total = sum(widths) + 3 * len(cols) + 1
        title = ((self.title, "italic"), (" " * (total - _cells(self.title)), ""))
        out: list[Line] = [title, ((" " * total, ""),)]
        right = [c.justify == "right" for c in cols]
        for n, (row, sizes) in enumerate(zip(cells, used, strict=True)):
            if max(map(len, row)) == 1 and all(map(int.__le__, sizes, widths)):
                out.append(_one_line(row, sizes, widths, right))  # most rows: no cell wraps
            else:
                out += _lines(row, widths, right, bottom=not n)
            if not n:  # the header's rule
                out.append(((" " + "\u2500" * (total - 2) + " ", ""),))
        out.append(((" " * total, ""),))
        return out if total <= width else [_crop(line, width) for line in out]


def _one_line(
    row: list[tuple[Line, ...]], sizes: list[int], widths: list[int], right: list[bool]
) -> Line:
    """A table's row of cells of one line each, each within its column's width."""
    spans: list[Span] = []
    plain = [" "]  # the table's edge; then plain text up to the next styled span
    for i, (lines, size, w, r) in enumerate(zip(row, sizes, widths, right, strict=True)):
        plain.append("  " if i else " ")  # a space between columns, the cell's padding
        pad = " " * (w - size)
        line = lines[0]
        if len(line) == 1 and not line[0][1]:  # most cells: plain text
            plain.append(pad + line[0][0] if r else line[0][0] + pad)
        else:
            if r:
                plain.append(pad)
            for text, style in line:
                if not style:
                    plain.append(text)
                    continue
                if any(plain):
                    spans.append(("".join(plain), ""))
                plain = []
                spans.append((text, style))
            if not r:
                plain.append(pad)
        plain.append(" ")
    plain.append(" ")
    spans.append(("".join(plain), ""))
    return tuple(spans)


def _lines(
    row: list[tuple[Line, ...]], widths: list[int], right: list[bool], bottom: bool
) -> list[Line]:
    """A table's row of cells of any lines, each wrapped at its column's width; the header's
    cells at the bottom of the row, the others at its top."""
    wrapped = [
        [(p, _width(p)) for line in lines for p in _wrap(line, w)]
        for lines, w in zip(row, widths, strict=True)
    ]
    height = max(len(parts) for parts in wrapped)
    out = []
    for n in range(height):
        spans: list[Span] = [(" ", "")]
        for i, (parts, w, r) in enumerate(zip(wrapped, widths, right, strict=True)):
            at = n - (height - len(parts)) if bottom else n
            line, used = parts[at] if 0 <= at < len(parts) else ((), 0)
            pad = " " * (w - used)
            if r:
                spans.append(("  " + pad if i else " " + pad, ""))
                spans += line
                spans.append((" ", ""))
            else:
                spans.append(("  " if i else " ", ""))
                spans += line
                spans.append((pad + " ", ""))
        spans.append((" ", ""))
        out.append(_join(spans))
    return out


def _join(spans: list[Span]) -> Line:
    """Spans of one style one after another as one span; empty ones left out."""
    out: list[Span] = []
    for text, style in spans:
        if not text:
            continue
        if out and out[-1][1] == style:
            out[-1] = (out[-1][0] + text, style)
        else:
            out.append((text, style))
    return tuple(out)


def _crop(line: Line, width: int) -> Line:
    """``line`` cut at ``width`` cells."""
    text = "".join(part for part, _ in line)
    return line if _cells(text) <= width else _slice(line, 0, _fit(text, 0, width))


class View:
    """What the monitor shows, laid out for a width on demand (:meth:`lines`): printable by
    rich (``console.print(view)``) and by :class:`Screen`."""

    def __init__(
        self,
        blocks: Sequence[Para | Grid],
        dim: bool = False,
        banner: Para | None = None,
        parts: Mapping[str, tuple[object, Para | Grid | None]] | None = None,
    ) -> None:
        self.blocks = blocks
        self.dim = dim
        self.banner = banner
        self.notes: list[Para] = []
        #: each part of the view by name: what it was built from, and the part (see render)
        self.parts = parts or {}
        self._laid: tuple[int, list[Line]] | None = None

    def lines(self, width: int) -> list[Line]:
        """The view's lines at ``width`` (none wider)."""
        width = max(width, 1)
        if self._laid is None or self._laid[0] != width:
            body = [line for block in self.blocks for line in block.lines(width)]
            if self.dim:
                body = [tuple((t, _style("dim", s)) for t, s in line) for line in body]
            banner = self.banner.lines(width) if self.banner else []
            notes = [line for note in self.notes for line in note.lines(width)]
            self._laid = (width, banner + body + notes)
        return self._laid[1]

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> Iterator[Segment]:
        for line in self.lines(options.max_width):
            for text, style in line:
                yield Segment(text, console.get_style(style) if style else None)
            yield Segment.line()


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
    motors = [_d(m) for m in _l(doc.get("motors"))]
    recent = _l(_d(doc.get("link")).get("recent"))[-RECENT_SHOWN:]
    inputs: dict[str, tuple[object, Callable[[], Para | Grid | None]]] = {
        "header": (
            (doc.get("executor"), doc.get("uptime_s"), doc.get("state"), bool(stale)),
            lambda: _header(doc, stale=bool(stale)),
        ),
        "motors": (doc.get("motors"), lambda: _motors(doc)),
        "timing": (
            [
                (m.get("index"), m.get("timing"), m.get("faults"), "timing" in m, "faults" in m)
                for m in motors
            ],
            lambda: _timing(doc),
        ),
        "steps": (
            (doc.get("steps"), doc.get("hard_stops"), doc.get("clamped")),
            lambda: _steps(doc),
        ),
        "io": ((doc.get("pins"), doc.get("dc"), "pins" in doc, "dc" in doc), lambda: _io(doc)),
        "link": ((doc.get("link"), rate), lambda: _link(doc, rate)),
        "trace": (doc.get("trace"), lambda: _trace(doc)),
        "recent": ((recent, doc.get("monotonic_s"), since_s), lambda: _recent(doc, since_s)),
        "drivers": (doc.get("drivers"), lambda: _drivers(doc)),
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
    return f"{seconds:.1f} s" if seconds < 60 else _duration(seconds)


def _header(doc: Mapping[str, Any], stale: bool = False) -> Para:
    ex = _d(doc.get("executor"))
    text = Para("motorctld", style="bold")
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


def _motors(doc: Mapping[str, Any]) -> Grid:
    table = Grid("motors")
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
        table.add_column(name, justify=justify)
    for m in _l(doc.get("motors")):
        m = _d(m)
        state = str(m.get("state", "?"))
        style = {"idle": "", "fault": "bold red"}.get(state, "bold green")
        fault = m.get("fault")
        fault_text = Para(str(fault), style="red") if fault else Para("")
        if m.get("position_lost"):
            fault_text.append(
                " (position lost: home it)" if fault else "position lost: home it", style="yellow"
            )
        table.add_row(
            str(m.get("index", "?")),
            str(m.get("name", "")),
            Para(state, style=style),
            _num(m.get("position")),
            _num(m.get("speed"), "{:,.0f}"),
            _num(m.get("queued")),
            _num(m.get("waypoints")),
            fault_text,
        )
    return table


def _timing(doc: Mapping[str, Any]) -> Grid | None:
    """Per-motor step timing and faults by cause (issue 15), when the daemon reports them."""
    motors = [_d(m) for m in _l(doc.get("motors"))]
    if not any("timing" in m or "faults" in m for m in motors):
        return None
    table = Grid("step timing per motor")
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
            str(m.get("index", "?")),
            _num(t.get("late_absorbed")),
            _num(t.get("slid_ms"), "{:,.1f}"),
            _num(t.get("worst_late_us"), "{:,.0f}"),
            _num(t.get("worst_lag_full_steps"), "{:,.2f}"),
            _num(t.get("max_lag_full_steps"), "{:,.2f}"),
            _num(t.get("microsteps")),
            _num(t.get("lag_faults")),
            faults,
        )
    return table


def _steps(doc: Mapping[str, Any]) -> Para:
    s = _d(doc.get("steps"))
    text = Para("step edges ", style="bold")
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


def _io(doc: Mapping[str, Any]) -> Para:
    text = Para("pins ", style="bold")
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


def _link(doc: Mapping[str, Any], rate: float | None) -> Para:
    link = _d(doc.get("link"))
    text = Para("link ", style="bold")
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


def _trace(doc: Mapping[str, Any]) -> Para | None:
    """The link's trace (motorctld --trace), when it records one."""
    t = _d(doc.get("trace"))
    if not t:
        return None
    text = Para("trace ", style="bold")
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


def _recent(doc: Mapping[str, Any], since_s: float) -> Grid:
    table = Grid("last frames")
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
            _num(age, "{:.1f}", "?"),
            str(r.get("frame", "")),
            str(r.get("command", "")),
            Para("(owed)" if result is None else str(result), style=style),
        )
    return table


def _drivers(doc: Mapping[str, Any]) -> Para | None:
    drivers = [_d(d) for d in _l(doc.get("drivers"))]
    if not drivers:
        return None
    text = Para("drivers", style="bold")
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


#: the terminal's control sequences :class:`Screen` writes itself
HOME_CLEAR = "\x1b[H\x1b[2J"
CLEAR_TO_END = "\x1b[K"


class Screen:
    """The terminal while the monitor runs: the alternate screen, the cursor hidden (as
    rich's live display with ``screen=True`` had it; :data:`~motorctl.daemon.status.monitor.
    SCREEN_OFF` puts it back as well). :meth:`draw` writes only the lines that differ from
    the ones on the screen (each where it goes), all of them once the size changed; lines
    below the screen's height are left out."""

    def __init__(self, console: Console) -> None:
        self.console = console
        self.shown: list[Line] = []
        self.size: tuple[int, int] | None = None
        self._color_system = COLOR_SYSTEMS.get(console.color_system or "")
        self._codes: dict[str, tuple[str, str]] = {}

    def __enter__(self) -> Screen:
        self.console.set_alt_screen(True)
        self.console.show_cursor(False)
        return self

    def __exit__(self, *exc: object) -> None:
        self.console.show_cursor(True)
        self.console.set_alt_screen(False)

    def draw(self, view: View, size: tuple[int, int]) -> str:
        """Bring the screen (``size``: columns, lines) to ``view``; what was written."""
        width, height = size
        lines = view.lines(width)[:height]
        out = []
        if size != self.size:
            self.size, self.shown = size, []
            out.append(HOME_CLEAR)
        for i, line in enumerate(lines):
            if i >= len(self.shown) or self.shown[i] != line:
                out.append(f"\x1b[{i + 1};1H{self._ansi(line, width)}")
        out += [f"\x1b[{i + 1};1H{CLEAR_TO_END}" for i in range(len(lines), len(self.shown))]
        self.shown = lines
        text = "".join(out)
        if text:
            self.console.file.write(text)
            self.console.file.flush()
        return text

    def _ansi(self, line: Line, width: int) -> str:
        """A line as the terminal's characters: its trailing plain spaces left out, the rest
        of the line cleared (unless the line fills it: the cursor then waits at its last
        column, where clearing would take that column's character)."""
        spans = list(line)
        while spans and not spans[-1][1] and not spans[-1][0].strip():
            spans.pop()
        if spans and not spans[-1][1]:
            spans[-1] = (spans[-1][0].rstrip(), "")
        out = []
        for text, style in spans:
            if style:
                start, end = self._sgr(style)
                out.append(f"{start}{text}{end}")
            else:
                out.append(text)
        return "".join(out) + (CLEAR_TO_END if _width(tuple(spans)) < width else "")

    def _sgr(self, style: str) -> tuple[str, str]:
        codes = self._codes.get(style)
        if codes is None:
            marked = self.console.get_style(style).render("\0", color_system=self._color_system)
            start, _, end = marked.partition("\0")
            codes = self._codes[style] = (start, end)
        return codes


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
