"""systemd glue, with systemd-python where it helps and no hard dependency on it.

- Notifications (READY=1, STATUS=..., STOPPING=1, WATCHDOG=1): ``systemd.daemon.notify``
  when python3-systemd is importable, else the built-in sender (one datagram to
  $NOTIFY_SOCKET). Not run by systemd: nothing is sent.
- Logging: to the journal with structured fields (MOTOR, COMMAND, ERROR_CODE, STATE_PATH,
  ERRNO, ... given as ``extra={"MOTOR": 0}``; upper-case keys become journal fields) when
  stderr is the journal stream systemd set up ($JOURNAL_STREAM) and ``systemd.journal`` is
  importable; to stderr otherwise.
- :class:`StatusLine`: systemd's STATUS= one-line summary, sent again whenever it changes.

Threads: :func:`sd_notify` may be called from any thread (one datagram, never blocks for
long). :class:`StatusLine` owns one thread that wakes on :meth:`StatusLine.poke` or every
``period`` seconds; :class:`Watchdog` owns another.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import socket
import sys
import threading
from collections.abc import Callable
from types import ModuleType
from typing import Any, TextIO

log = logging.getLogger("motorctl.service")


def _import(name: str) -> ModuleType | None:
    """A systemd-python module, or None when python3-systemd is not installed."""
    try:
        return __import__(name, fromlist=["_"])
    except ImportError:
        return None


def notify_builtin(message: str) -> bool:
    """The sd_notify protocol by hand: one datagram to $NOTIFY_SOCKET."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):
        address = "\0" + address[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.connect(address)
            sock.sendall(message.encode())
    except OSError as exc:
        log.warning("cannot notify systemd at %s: %s", os.environ.get("NOTIFY_SOCKET"), exc)
        return False
    return True


def notify_backend() -> tuple[str, Callable[[str], bool]]:
    """("systemd-python", systemd.daemon.notify) when importable, else the built-in one."""
    daemon = _import("systemd.daemon")
    if daemon is not None:
        notify: Callable[[str], bool] = daemon.notify

        def send(message: str) -> bool:
            if not os.environ.get("NOTIFY_SOCKET"):
                return False
            return bool(notify(message))

        return "systemd-python", send
    return "built-in", notify_builtin


_BACKEND: list[Callable[[str], bool]] = []  # chosen once, on first use


def sd_notify(message: str) -> bool:
    """Send ``message`` (e.g. "READY=1") to systemd; False when not run by systemd."""
    if not _BACKEND:
        _BACKEND.append(notify_backend()[1])
    return _BACKEND[0](message)


# -- logging -------------------------------------------------------------------------------
def journal_stream_is_stderr(stderr: TextIO | None = None) -> bool:
    """True when systemd connected our stderr to the journal ($JOURNAL_STREAM = dev:ino)."""
    value = os.environ.get("JOURNAL_STREAM", "")
    dev, _, ino = value.partition(":")
    if not dev.isdigit() or not ino.isdigit():
        return False
    try:
        st = os.fstat((stderr or sys.stderr).fileno())
    except (OSError, ValueError):
        return False
    return (st.st_dev, st.st_ino) == (int(dev), int(ino))


_PRIORITY = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}


class JournalHandler(logging.Handler):
    """Log records as journal entries; upper-case ``extra`` keys become fields."""

    def __init__(self, send: Callable[..., Any], identifier: str = "motorctld") -> None:
        super().__init__()
        self._send = send
        self.identifier = identifier

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = self.format(record)
            fields = {
                k: str(v)
                for k, v in record.__dict__.items()
                if k.isupper() and k.replace("_", "").isalnum() and v is not None
            }
            self._send(
                message,
                PRIORITY=str(_PRIORITY.get(record.levelno, 6)),
                SYSLOG_IDENTIFIER=self.identifier,
                LOGGER=record.name,
                THREAD_NAME=record.threadName or "",
                CODE_FILE=record.pathname,
                CODE_LINE=record.lineno,
                CODE_FUNC=record.funcName,
                **fields,
            )
        except Exception:
            self.handleError(record)


class FieldsFormatter(logging.Formatter):
    """stderr: the message, then the structured fields as KEY=value."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        fields = [
            f"{k}={v}" for k, v in sorted(record.__dict__.items()) if k.isupper() and v is not None
        ]
        return f"{text} [{' '.join(fields)}]" if fields else text


class StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to ``stream`` if given, else to whatever ``sys.stderr`` is when it writes (as
    logging.lastResort does), so it never holds on to a stream someone has replaced."""

    def __init__(self, stream: TextIO | None = None) -> None:
        super().__init__(stream)  # which sets self.stream = stream or sys.stderr ...
        self._fixed = stream  # ... so say again which: None means "the current sys.stderr"

    @property
    def stream(self) -> TextIO:
        return self._fixed or sys.stderr

    @stream.setter
    def stream(self, value: TextIO | None) -> None:
        self._fixed = value


def setup_logging(level: str, stderr: TextIO | None = None) -> str:
    """Configure the root logger; returns "journal" or "stderr" (where logs go).

    Replaces the handler an earlier call installed, and leaves other handlers alone.
    """
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, "motorctl", False):
            root.removeHandler(handler)
    root.setLevel(level.upper())
    journal = _import("systemd.journal") if journal_stream_is_stderr(stderr) else None
    new: logging.Handler
    if journal is not None:
        new = JournalHandler(journal.send)
        new.setFormatter(logging.Formatter("%(message)s"))
        where = "journal"
    else:
        new = StderrHandler(stderr)
        new.setFormatter(FieldsFormatter("motorctld %(levelname)s %(name)s: %(message)s"))
        where = "stderr"
    setattr(new, "motorctl", True)  # noqa: B010 (marks the handler this function owns)
    root.addHandler(new)
    return where


def watchdog_interval() -> float | None:
    """Half of systemd's WatchdogSec for this process, or None when there is no watchdog."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    if not usec.isdigit() or int(usec) == 0:  # as sd_watchdog_enabled(): not a watchdog
        log.warning(
            "WATCHDOG_USEC=%r is not a number of microseconds > 0: no watchdog pings "
            "(systemd sets it from WatchdogSec=; do not set it by hand)",
            usec,
        )
        return None
    return int(usec) / 2e6


class Watchdog:
    """Pings systemd while ``healthy()`` holds; a hung daemon gets restarted by systemd."""

    def __init__(self, interval: float, healthy: Callable[[], bool]) -> None:
        self.interval = interval
        self.healthy = healthy
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="motorctl-watchdog", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            if self.healthy():
                sd_notify("WATCHDOG=1")


class ProgressWatch:
    """The watchdog's meaning of "healthy" (issue 7): every part made progress lately.

    ``parts`` maps a name to a probe returning a progress counter, or None when the part
    cannot progress at all (dead). A part is healthy when its counter moved since the
    previous look (``pokes`` make idle parts move: the link loop is woken after each look, so
    a loop blocked waiting for bytes still turns) or when the probe says it has nothing to
    do (``IDLE``). The watchdog thread calls :meth:`healthy` every interval; the first hung
    part is logged once per episode. Owner: the watchdog thread.
    """

    IDLE = -1

    def __init__(
        self,
        parts: dict[str, Callable[[], int | None]],
        pokes: tuple[Callable[[], None], ...] = (),
    ) -> None:
        self.parts = parts
        self.pokes = pokes
        self._last: dict[str, int | None] = {}
        self.hung: str | None = None

    def healthy(self) -> bool:
        hung = None
        for name, probe in self.parts.items():
            now = probe()
            before = self._last.get(name)
            self._last[name] = now
            if now is None:
                hung = hung or f"{name}: dead"
            elif now != self.IDLE and before is not None and now == before:
                hung = hung or f"{name}: no progress"
        if hung != self.hung:
            if hung is not None:
                log.error("watchdog not fed: %s", hung)
            else:
                log.info("watchdog fed again: every part makes progress")
            self.hung = hung
        for poke in self.pokes:
            poke()
        return hung is None


class StatusLine:
    """systemd's STATUS=: a one-line summary from ``summary()``, sent whenever it changes.

    ``poke()`` (any thread, never blocks) asks for a fresh look now; without pokes the line
    is looked at every ``period`` seconds (counters such as frames served change quietly).
    """

    def __init__(
        self,
        summary: Callable[[], str],
        send: Callable[[str], bool] = sd_notify,
        period: float = 2.0,
        before: Callable[[], None] = lambda: None,
    ) -> None:
        self.summary = summary
        self.before = before  # e.g. MotorEventLog.flush, on this thread
        self.send = send
        self.period = period
        self.last: str | None = None
        self.sent = 0
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="motorctl-status-line", daemon=True)

    def start(self) -> None:
        self.update()
        self._thread.start()

    def poke(self) -> None:
        self._wake.set()

    def update(self) -> None:
        try:
            self.before()
            line = self.summary()
        except Exception:  # a status line must never take the daemon down
            log.exception("cannot build the status line")
            return
        if line != self.last:
            self.last = line
            self.send(f"STATUS={line}")
            self.sent += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.period)
            self._wake.clear()
            if self._stop.is_set():
                return
            self.update()

    def stop(self, final: str | None = None) -> None:
        """Stop the thread; send ``final`` (e.g. "stopping: motors ramping down") if given."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        with contextlib.suppress(Exception):
            self.before()
        if final is not None and final != self.last:
            self.last = final
            self.send(f"STATUS={final}")
            self.sent += 1


_EVENT_LEVELS = {"fault": logging.ERROR, "cleared": logging.INFO, "homed": logging.INFO}
#: (motor, name, event, fault, cause, position lost)
_Event = tuple[int, str, str, str | None, str | None, bool]


class MotorEventLog:
    """Motor faults, clears and homings as journal entries, logged off the step thread.

    ``record()`` is called from motor listeners (step thread, engine lock held): it only
    appends to a bounded queue. ``flush()`` logs on the caller's thread (the status line's),
    with the fields MOTOR, MOTOR_NAME, EVENT and FAULT, and for a fault CAUSE (what it is
    counted under in the status: timing_lost, endstop, driver ...) and POSITION_LOST.
    """

    def __init__(self, limit: int = 256) -> None:
        self._pending: collections.deque[_Event] = collections.deque(maxlen=limit)
        self._lock = threading.Lock()

    def record(
        self,
        index: int,
        name: str,
        event: str,
        fault: str | None,
        cause: str | None = None,
        lost: bool = False,
    ) -> bool:
        """Queue an event worth a log line; True when it was one."""
        if event not in _EVENT_LEVELS:
            return False
        with self._lock:
            self._pending.append((index, name, event, fault, cause, lost))
        return True

    def flush(self) -> None:
        with self._lock:
            events, self._pending = (
                list(self._pending),
                collections.deque(maxlen=self._pending.maxlen),
            )
        for index, name, event, fault, cause, lost in events:
            lost_text = "position lost (home it again); " if lost else ""
            text = {
                "fault": f"fault latched: {fault}; {lost_text}E4 until StopMove clears it",
                "cleared": "fault cleared",
                "homed": "homed: position 0",
            }[event]
            fields: dict[str, object] = {
                "MOTOR": index,
                "MOTOR_NAME": name,
                "EVENT": event,
                "FAULT": fault,
            }
            if event == "fault":
                fields.update(CAUSE=cause, POSITION_LOST=int(lost))
            log.log(_EVENT_LEVELS[event], "motor %d (%s): %s", index, name, text, extra=fields)
