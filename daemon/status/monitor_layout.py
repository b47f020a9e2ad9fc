"""The layout of the live monitor's view: styled text as lines of (text, style) spans,
for a width. :class:`Para` is a text of one or more lines (rich's ``Text`` with a base
style), :class:`Grid` a table laid out as lines (rich's ``box.SIMPLE_HEAD`` look), and
:class:`View` the whole view: its blocks, dimmed and under a banner when it is stale, laid
out at a width on demand (:meth:`View.lines`) and cached under that width. rich prints a
view (``console.print(view)``: ``--once``, off a terminal, the tests), and on a terminal
:class:`~motorctl.daemon.status.monitor_screen.Screen` writes its lines itself: one
layout, two ways out (rich's own tables cost some 10-20 ms of CPU a drawing).

Only the monitor's modules import this one (it imports ``rich``, which the daemon never
does). Threads: no thread of its own; each object here belongs to the thread that builds
it, the monitor's drawing thread (a view and its laid-out lines are not shared).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

from rich.cells import cell_len
from rich.console import Console, ConsoleOptions
from rich.segment import Segment

Span = tuple[str, str]  # text, a rich style definition ("" plain)
Line = tuple[Span, ...]


def _style(base: str, style: str) -> str:
    return f"{base} {style}" if base and style else base or style


def _cells(text: str) -> int:
    """The columns ``text`` takes on a terminal."""
    return len(text) if text.isascii() else cell_len(text)


def line_width(line: Line) -> int:
    """The columns ``line`` takes on a terminal."""
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
    """A column of a :class:`Grid`: its header, how its cells are justified, and whether
    they may wrap."""

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
                    used[-1].append(max(map(line_width, lines)))
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
        [(p, line_width(p)) for line in lines for p in _wrap(line, w)]
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
    rich (``console.print(view)``) and by
    :class:`~motorctl.daemon.status.monitor_screen.Screen`."""

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
