"""The live monitor's entry point (``motorctl monitor``, ``motorctld --status --watch``),
free of the terminal library: it finds out whether ``rich`` is there and says what to
install when it is not; the view itself is :mod:`motorctl.daemon.status.monitor_view`.

``rich`` is an optional dependency (the ``monitor`` extra; Debian: python3-rich): the
daemon never imports it. The monitor reads only the status socket (docs/status.md), so it
runs beside the daemon, e.g. in an SSH session on the board.

Threads: the caller's thread draws; one reader thread per connection follows the
subscription (:mod:`motorctl.daemon.status.monitor_view`).
"""

from __future__ import annotations

import sys
from pathlib import Path

RICH_MISSING = (
    "the live monitor needs the Python package 'rich', which is not installed: "
    "'apt install python3-rich' (Debian, Raspberry Pi OS) or "
    "'pip install motorctl[monitor]'; the daemon itself does not need it, and "
    "'motorctld --status' prints the same figures as JSON"
)


def run(path: Path, period_ms: int, once: bool = False) -> int:
    """Show the daemon's status at ``path``: refreshing until Ctrl-C, or ``once``."""
    try:
        from motorctl.daemon.status import monitor_view
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != "rich":
            raise
        print(f"error: {RICH_MISSING}", file=sys.stderr)
        return 1
    if once:
        return monitor_view.once(path)
    return monitor_view.watch(path, period_ms)
