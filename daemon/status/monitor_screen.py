"""The live monitor on a terminal: :class:`Screen` holds the alternate screen
(the cursor hidden) while the monitor runs, and brings it to a view by writing only the
lines that changed since its last drawing, each where it goes, all of them once the
terminal's size changed (rich's live display redrew the whole view every time).

Threads: a :class:`Screen` belongs to the monitor's drawing thread (the caller's thread of
:func:`~motorctl.daemon.status.monitor_view.watch`), which alone draws with it.
"""

from __future__ import annotations

from rich.console import COLOR_SYSTEMS, Console

from motorctl.daemon.status.monitor_layout import Line, View, line_width

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
        return "".join(out) + (CLEAR_TO_END if line_width(tuple(spans)) < width else "")

    def _sgr(self, style: str) -> tuple[str, str]:
        codes = self._codes.get(style)
        if codes is None:
            marked = self.console.get_style(style).render("\0", color_system=self._color_system)
            start, _, end = marked.partition("\0")
            codes = self._codes[style] = (start, end)
        return codes
