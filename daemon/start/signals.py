"""The stop signals: SIGTERM, SIGINT and SIGHUP stop the daemon cleanly.

Threads: installed by the main thread (Python runs signal handlers there, between
bytecodes); see :class:`StopSignals`.
"""

from __future__ import annotations

import logging
import signal
from collections.abc import Callable
from types import FrameType

log = logging.getLogger("motorctl")


class StopSignals:
    """SIGTERM, SIGINT and SIGHUP all stop the daemon cleanly (docs/service.md says why).

    Installed first thing (main thread), so a signal during start-up is not lost: it is
    remembered and the daemon stops as soon as it could serve.

    Python runs a signal's handler in the main thread between bytecodes only: a signal that
    arrives just before the link loop's ``poll()`` (or is taken by another thread) would
    wait for the next byte from the host, for ever on an idle, open port. :meth:`attach`
    therefore also makes the link's wake-up pipe the signal wake-up descriptor
    (``signal.set_wakeup_fd``): the signal itself ends that ``poll()``. :meth:`detach`
    undoes it before the pipe is closed; later signals are only logged.
    """

    SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)

    def __init__(self) -> None:
        self.requested: str | None = None
        self._stop: Callable[[], None] | None = None
        self._wakeup: int | None = None  # the descriptor it replaced, while attached
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}

    def attach(self, stop: Callable[[], None], wakeup_fd: int | None = None) -> None:
        """Call ``stop`` on a signal (at once if one came already); ``wakeup_fd``: a
        non-blocking descriptor the signal itself writes a byte to (main thread only)."""
        self._stop = stop
        if wakeup_fd is not None:
            old = signal.set_wakeup_fd(wakeup_fd, warn_on_full_buffer=False)
            if self._wakeup is None:
                self._wakeup = old
        if self.requested is not None:
            stop()

    def detach(self) -> None:
        """Before the wake-up descriptor is closed: signals from now on are only logged."""
        self._stop = None
        if self._wakeup is not None:
            signal.set_wakeup_fd(self._wakeup)
            self._wakeup = None

    def restore(self) -> None:
        """Detach and give the signals back the handlers they had (tests in one process)."""
        self.detach()
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        again = self.requested is not None
        self.requested = name
        how = (
            " (the terminal closed, or someone asked): stopping as for SIGTERM"
            if signum == signal.SIGHUP
            else ": stopping"
        )
        if again:
            how = ": already stopping"
        log.info("%s%s", name, how, extra={"SIGNAL": name})
        if self._stop is not None:
            self._stop()
