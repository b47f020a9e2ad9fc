"""The daemon's start-up error, below everything that raises it.

:class:`StartupError` is what the user must fix before the daemon can start (a device or a
path that cannot be used, hardware that cannot be opened, an unwritable state directory);
``motorctld`` prints its message and exits 1 (daemon/start/main.py). The assembler, the serve
module and the link's ports raise it; it lives here so that none of them imports another
for it.

No state, no threads.
"""

from __future__ import annotations


class StartupError(Exception):
    """Something the user must fix before the daemon can start; the message says what."""
