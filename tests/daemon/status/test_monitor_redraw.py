"""When the live monitor draws, and what a drawing writes (issue 36: the monitor at 10 Hz
under 1 % of a CPU): a drawing only when what it shows changes (:class:`Watched`, its
clock given to it: no timed test), of the lines that changed (:class:`Screen`), from one
layout that rich prints as well; a view built on the last one is the same view.

The drawing's cost itself is measured, not tested: bench/status_rate.py (docs/timing.md,
"The monitor process's own CPU")."""

from __future__ import annotations

import copy
import io
import re
import threading
from pathlib import Path
from typing import Any

from rich.console import Console

from motorctl.daemon.status.monitor import Ending
from motorctl.daemon.status.monitor_layout import View
from motorctl.daemon.status.monitor_screen import HOME_CLEAR, Screen
from motorctl.daemon.status.monitor_view import Seen, Watched, render, watch
from motorctl.daemon.status.server import StatusServer
from tests.daemon.status.test_metrics import DOC
from tests.support.wait import until

PERIOD_S = 0.1
PATH = Path("/run/motorctl/status.sock")
#: where a Screen puts a line: ESC [ row ; 1 H
AT = re.compile(r"\x1b\[(\d+);1H")


def moved(doc: dict[str, Any], motor: int, position: int, t: float) -> dict[str, Any]:
    """``doc`` a moment later (its clock at ``t``) with ``motor`` at ``position``."""
    doc = copy.deepcopy(doc)
    doc["motors"][motor]["position"] = position
    doc["monotonic_s"] = t
    return doc


def at_rest(watched: Watched, start: float, seconds: float) -> list[float]:
    """The moments, one a period from ``start`` for ``seconds``, at which what the view
    shows differs from the moment before (a drawing is due)."""
    due = []
    shown = watched.shown(start)
    for n in range(1, round(seconds / PERIOD_S) + 1):
        now = start + n * PERIOD_S
        if watched.shown(now) != shown:
            shown = watched.shown(now)
            due.append(round(now - start, 3))
    return due


def test_no_drawing_at_rest_but_once_a_second() -> None:
    watched = Watched(PERIOD_S, PATH)
    watched.take(Seen(DOC, 100.0))
    # at rest (no update) for 9 periods: nothing shown changes, nothing is drawn
    assert at_rest(watched, 100.0, 0.9) == []
    # then the ages move by a whole second, once a second: 10 drawings in 10 s, not 100
    assert at_rest(watched, 100.0, 10.0) == [float(s) for s in range(1, 11)]
    assert "updated 3 s ago;" in text(watched.view(103.95))


def test_frames_per_second_falling_to_zero_is_drawn() -> None:
    watched = Watched(PERIOD_S, PATH)
    earlier = moved(DOC, 0, -12, 4.9)
    earlier["link"]["counters"]["frames"] -= 5
    watched.take(Seen(earlier, 99.9))
    watched.take(Seen(DOC, 100.0))
    assert "(50.0/s)" in text(watched.view(100.0))
    # the rate goes to 0 once no update came for a period and a half (and half a second)
    assert at_rest(watched, 100.0, 0.9) == [0.7]
    assert "(0.0/s)" in text(watched.view(100.7))


def test_a_motor_moving_is_drawn_at_once() -> None:
    watched = Watched(PERIOD_S, PATH)
    watched.take(Seen(DOC, 100.0))
    before = watched.shown(100.05)
    watched.take(Seen(moved(DOC, 1, 4321, 5.05), 100.05))
    assert watched.shown(100.05) != before
    row = next(line for line in text(watched.view(100.05)).splitlines() if " y " in line)
    assert row.split()[:4] == ["1", "y", "idle", "4,321"]


def test_the_daemon_gone_is_drawn_at_once_then_once_a_second() -> None:
    watched = Watched(PERIOD_S, PATH)
    watched.take(Seen(DOC, 100.0))
    before = watched.shown(100.3)
    watched.take(f"motorctld at {PATH} stopped")
    assert watched.shown(100.3) != before
    stale = text(watched.view(100.3))
    assert stale.startswith(f"NOT LIVE: motorctld at {PATH} stopped.")
    assert "0.0 s ago" in stale.splitlines()[0] and " alive" not in stale
    assert at_rest(watched, 100.3, 2.0) == [0.7, 1.7]  # its age: whole seconds
    watched.take(Seen(DOC, 102.5))  # back
    assert "NOT LIVE" not in text(watched.view(102.5))


def test_a_view_built_on_the_last_one_is_the_same_view() -> None:
    """render(before=) takes over the parts built from the same inputs, and only those."""
    first = render(DOC, 12.5, since_s=1.0, note="n")
    second_doc = moved(DOC, 0, 77, 5.5)
    second = render(second_doc, 12.5, since_s=1.0, note="n", before=first)
    assert second.lines(140) == render(second_doc, 12.5, since_s=1.0, note="n").lines(140)
    assert second.parts["motors"][1] is not first.parts["motors"][1]  # a motor moved
    assert second.parts["recent"][1] is not first.parts["recent"][1]  # ages: the clock
    for same in ("timing", "io", "link", "drivers"):
        assert second.parts[same][1] is first.parts[same][1], same
    stale = render(second_doc, 12.5, since_s=1.0, stale="gone", before=second)
    assert stale.lines(140) == render(second_doc, 12.5, since_s=1.0, stale="gone").lines(140)
    assert stale.parts["link"][1] is not second.parts["link"][1]  # no rate read as live


def text(view: View, width: int = 140) -> str:
    console = Console(width=width, record=True, file=io.StringIO(), color_system=None)
    console.print(view)
    return console.export_text()


def terminal(width: int = 140, height: int = 60) -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(file=out, width=width, height=height, force_terminal=True), out


def plain(written: str) -> str:
    """What a terminal was sent, its colours (and line ends cleared) left out."""
    return re.sub(r"\x1b\[[0-9;]*[mK]", "", written)


def screen_lines(written: str) -> dict[int, str]:
    """What a Screen's drawing put on each line (1-based), its colours left out."""
    parts = AT.split(written)
    return {int(row): plain(content) for row, content in zip(parts[1::2], parts[2::2], strict=True)}


def test_the_screen_shows_what_rich_prints() -> None:
    """One layout: a Screen's first drawing holds, line for line, what rich prints."""
    console, _ = terminal()
    view = render(DOC, 12.5, since_s=0.25, note="updated 0 s ago")
    written = Screen(console).draw(view, (140, 60))
    assert written.startswith(HOME_CLEAR)
    printed = text(view).splitlines()
    assert screen_lines(written) == {n + 1: line.rstrip() for n, line in enumerate(printed)}


def test_the_screen_writes_only_the_lines_that_changed() -> None:
    console, out = terminal()
    screen = Screen(console)
    first = render(DOC, 12.5, note="updated 0 s ago")
    whole = screen.draw(first, (140, 60))
    assert screen.draw(first, (140, 60)) == ""  # the same view: nothing written
    second = render(moved(DOC, 1, 4321, 5.0), 12.5, note="updated 0 s ago", before=first)
    changed = screen.draw(second, (140, 60))
    assert list(screen_lines(changed).values()) == [
        next(line for line in text(second).splitlines() if "4,321" in line).rstrip()
    ]
    assert len(changed) < len(whole) / 20
    assert out.getvalue() == whole + changed


def test_the_screen_redraws_all_of_a_resized_terminal_and_clears_what_is_gone() -> None:
    console, _ = terminal()
    screen = Screen(console)
    view = render(DOC, 12.5, note="updated 0 s ago")
    full = len(view.lines(100))
    assert len(screen_lines(screen.draw(view, (140, 60)))) == len(view.lines(140))
    resized = screen.draw(view, (100, 20))  # narrower and shorter: all of it again, cut
    assert resized.startswith(HOME_CLEAR) and sorted(screen_lines(resized)) == list(range(1, 21))
    assert all(len(line) <= 100 for line in screen_lines(resized).values())
    short = render({}, note="x")  # fewer lines: the rest of the old drawing cleared
    cleared = screen_lines(screen.draw(short, (100, 20)))
    assert full > 20 and all(cleared[n] == "" for n in range(len(short.lines(100)) + 1, 21))


def test_watch_on_a_terminal_draws_on_its_own_screen_and_gives_it_back(
    doc_server: StatusServer,
) -> None:
    console, out = terminal(width=140, height=60)
    ending = Ending()
    thread = threading.Thread(
        target=watch, args=(doc_server.path, 50, console, ending), daemon=True
    )
    thread.start()
    try:
        until("the first drawing", lambda: "compiled core (pid 12)" in plain(out.getvalue()))
    finally:
        ending.request()
        thread.join(10)
    assert not thread.is_alive()
    written = out.getvalue()
    assert written.startswith("\x1b[?1049h")  # the alternate screen, as rich's Live had it
    assert written.endswith("\x1b[?25h\x1b[?1049l")  # the cursor and the main screen back
    assert "\x1b[?25l" in written  # the cursor hidden meanwhile
    assert "updated 0 s ago;" in written
