"""The live monitor's entry point (``motorctl monitor``, ``motorctld --status --watch``),
free of the terminal library: it finds out whether ``rich`` is there and says what to
install when it is not; the view itself is :mod:`motorctl.daemon.status.monitor_view`.

``rich`` is an optional dependency (the ``monitor`` extra; Debian: python3-rich): the
daemon never imports it. The monitor reads only the status socket (docs/status.md), so it
runs beside the daemon, e.g. in an SSH session on the board.

SIGINT and SIGTERM end the monitor at any moment, within a second (:func:`end_on_signals`):
the monitor's entry points (``motorctld``'s, daemon/start/launch.py, first thing; :func:`run`)
make sure of it.

Threads: the caller's thread draws; one reader thread per connection follows the
subscription (:mod:`motorctl.daemon.status.monitor_view`). Signal handlers: the main
thread's, installed by the entry point (a program's, not a library's).
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path
from types import FrameType

RICH_MISSING = (
    "the live monitor needs the Python package 'rich', which is not installed: "
    "'apt install python3-rich' (Debian, Raspberry Pi OS) or "
    "'pip install motorctl[monitor]'; the daemon itself does not need it, and "
    "'motorctld --status' prints the same figures as JSON"
)


#: after SIGINT or SIGTERM, how long the monitor has to end in order before it is cut short
GRACE_S = 0.3
#: what puts a terminal back as the monitor's screen found it: the cursor shown, the main
#: screen back (monitor_screen.Screen leaves the same way)
SCREEN_OFF = b"\x1b[?25h\x1b[?1049l"


class Ending:
    """How the live monitor ends: on SIGINT or SIGTERM, at any moment, within a second.

    As the signals' handler (:func:`end_on_signals`) it only notes the request: the drawing
    loop looks at :attr:`requested` at least every 0.1 s and ends in order (the terminal's
    screen restored, then :meth:`finished`: exit status 0 at once). It raises nothing: a
    KeyboardInterrupt raised into whatever the main thread runs at that moment can be lost
    (one raised inside a weakref callback of the import system is printed as "Exception
    ignored" and the import goes on: the monitor kept running). An end not done
    ``grace_s`` after the first signal (the signal came while the modules were still being
    imported, or the end is stuck writing to a pipe nobody reads) is cut short: the
    terminal put back if the monitor's screen is on (:attr:`screen`, kept by the view),
    then exit status 0 at once. Main thread only (signal handlers); :attr:`requested` and
    :attr:`screen` are plain flags the main thread reads."""

    def __init__(self, grace_s: float = GRACE_S) -> None:
        self.grace_s = grace_s
        self.requested = False
        self.signalled = False  # requested by SIGINT or SIGTERM
        self.screen = False

    def request(self) -> None:
        """End the monitor in order (from any thread; no cut short)."""
        self.requested = True

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if not self.signalled:
            self.requested = self.signalled = True
            signal.signal(signal.SIGALRM, self._cut_short)
            signal.setitimer(signal.ITIMER_REAL, self.grace_s)

    def finished(self) -> None:
        """The monitor ended in order. Asked by a signal: what it drew is flushed (a pipe
        nobody reads may hold that up: the grace still runs) and the process exits at once,
        status 0: the interpreter's own exit (its modules torn down one by one) would take
        up most of the second on a busy machine, and there is nothing else to end."""
        if self.signalled:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)

    def _cut_short(self, signum: int, frame: FrameType | None) -> None:
        if self.screen and os.isatty(sys.stdout.fileno()):
            os.write(sys.stdout.fileno(), SCREEN_OFF)
        os._exit(0)


def end_on_signals(grace_s: float = GRACE_S) -> Ending:
    """From now on SIGINT and SIGTERM end this process (:class:`Ending`), whatever their
    disposition was: also where the process started with SIGINT ignored, as a shell starts
    a program in the background (Python then leaves it ignored, and the monitor never
    ended on it); SIGTERM's default (an end on the spot) would leave a terminal on the
    monitor's screen. The entry points call it first thing; a second call returns the
    :class:`Ending` installed."""
    installed = signal.getsignal(signal.SIGINT)
    if isinstance(installed, Ending):
        return installed
    ending = Ending(grace_s)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, ending)
    return ending


def run(path: Path, period_ms: int, once: bool = False) -> int:
    """Show the daemon's status at ``path``: refreshing until Ctrl-C or SIGTERM (exit
    status 0), or ``once``."""
    ending = None if once else end_on_signals()
    try:
        from motorctl.daemon.status import monitor_view
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != "rich":
            raise
        print(f"error: {RICH_MISSING}", file=sys.stderr)
        return 1
    if ending is None:
        return monitor_view.once(path)
    try:
        return monitor_view.watch(path, period_ms, ending=ending)
    finally:
        ending.finished()
