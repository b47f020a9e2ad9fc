"""systemd glue (daemon/service.py): notifications on a fake NOTIFY_SOCKET (built-in and
via systemd.daemon), journal logging with structured fields, the STATUS= line, the
watchdog and its idea of progress, motor events logged off the step thread."""

from __future__ import annotations

import errno
import logging
import os
import socket
import sys
import threading
import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.daemon import service
from motorctl.daemon.service import ProgressWatch

DEADLINE_S = 5.0


class FakeSystemd:
    """A datagram socket where systemd would listen; what the daemon sends arrives here."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))

    def recv(self) -> str:
        self.sock.settimeout(DEADLINE_S)
        try:
            return self.sock.recv(4096).decode()
        except TimeoutError:
            raise AssertionError(f"nothing sent to {self.path} within {DEADLINE_S} s") from None


@pytest.fixture
def fake_systemd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeSystemd]:
    fake = FakeSystemd(tmp_path / "notify.sock")
    monkeypatch.setenv("NOTIFY_SOCKET", str(fake.path))
    monkeypatch.setattr(service, "_BACKEND", [])
    yield fake
    fake.sock.close()


@pytest.fixture
def no_systemd_python(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(service, "_import", lambda name: None)


def fake_module(monkeypatch: pytest.MonkeyPatch, name: str, **attrs: Any) -> types.ModuleType:
    """systemd-python's API, standing in where the package is not installed."""
    mod = types.ModuleType(name)
    for k, v in attrs.items():
        setattr(mod, k, v)
    monkeypatch.setitem(sys.modules, name, mod)
    if "systemd" not in sys.modules or not hasattr(sys.modules["systemd"], "__path__"):
        pkg = types.ModuleType("systemd")
        pkg.__path__ = []
        monkeypatch.setitem(sys.modules, "systemd", pkg)
    setattr(sys.modules["systemd"], name.rsplit(".", 1)[1], mod)
    return mod


# -- notifications ----------------------------------------------------------------------------
def test_builtin_notify(fake_systemd: FakeSystemd, no_systemd_python: None) -> None:
    assert service.notify_backend()[0] == "built-in"
    assert service.sd_notify("READY=1")
    assert fake_systemd.recv() == "READY=1"


def test_builtin_notify_abstract_socket(
    monkeypatch: pytest.MonkeyPatch, no_systemd_python: None
) -> None:
    name = f"motorctl-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        monkeypatch.setenv("NOTIFY_SOCKET", "@" + name)
        assert service.notify_builtin("STOPPING=1")
        sock.settimeout(DEADLINE_S)
        assert sock.recv(100) == b"STOPPING=1"


def test_notify_without_systemd(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert not service.notify_builtin("READY=1")
    monkeypatch.setenv("NOTIFY_SOCKET", "/nonexistent/notify.sock")
    assert not service.notify_builtin("READY=1")  # logged, never raised
    assert "cannot notify systemd" in caplog.text


def test_notify_through_systemd_python(
    fake_systemd: FakeSystemd, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []

    def notify(message: str) -> bool:  # systemd.daemon.notify's signature and result
        calls.append(message)
        return service.notify_builtin(message)

    fake_module(monkeypatch, "systemd.daemon", notify=notify)
    assert service.notify_backend()[0] == "systemd-python"
    assert service.sd_notify("STATUS=hello")
    assert fake_systemd.recv() == "STATUS=hello"
    assert calls == ["STATUS=hello"]
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert not service.sd_notify("READY=1")
    assert calls == ["STATUS=hello"]


def test_status_line_sends_changes_only(fake_systemd: FakeSystemd, no_systemd_python: None) -> None:
    text = ["2 motors: 0 moving"]
    line = service.StatusLine(lambda: text[0], period=60.0)
    line.start()
    assert fake_systemd.recv() == "STATUS=2 motors: 0 moving"
    text[0] = "2 motors: 1 moving"
    line.poke()
    assert fake_systemd.recv() == "STATUS=2 motors: 1 moving"
    line.poke()  # unchanged: nothing sent
    line.stop("stopping")
    assert fake_systemd.recv() == "STATUS=stopping"
    assert line.sent == 3


def test_status_line_survives_a_failing_summary(caplog: pytest.LogCaptureFixture) -> None:
    sent: list[str] = []

    def broken() -> str:
        raise RuntimeError("boom")

    def send(message: str) -> bool:
        sent.append(message)
        return True

    line = service.StatusLine(broken, send=send)
    line.update()
    assert sent == [] and "cannot build the status line" in caplog.text


def test_watchdog_pings_only_while_healthy(
    fake_systemd: FakeSystemd, no_systemd_python: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "20000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    interval = service.watchdog_interval()
    assert interval is not None and interval == pytest.approx(0.01)
    healthy = threading.Event()
    healthy.set()
    dog = service.Watchdog(interval, healthy.is_set)
    dog.start()
    assert fake_systemd.recv() == "WATCHDOG=1"
    dog.stop()
    monkeypatch.setenv("WATCHDOG_PID", "1")
    assert service.watchdog_interval() is None


@pytest.mark.parametrize("usec", ["abc", "-5", "0", "1.5"])
def test_a_watchdog_usec_that_is_no_interval_is_no_watchdog(
    usec: str, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Set by hand (an environment file, a shell): 'abc' was int()'s ValueError at start, a
    negative one a watchdog thread pinging without a pause. No watchdog, one warning."""
    monkeypatch.setenv("WATCHDOG_USEC", usec)
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert service.watchdog_interval() is None
    assert f"WATCHDOG_USEC={usec!r} is not a number of microseconds > 0" in caplog.text


# -- logging ------------------------------------------------------------------------------------
# setup_logging() configures the root logger: tests/conftest.py puts it back after each test.


def test_logging_to_stderr_with_fields(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    with open(tmp_path / "err", "w+") as err:
        assert service.setup_logging("info", err) == "stderr"
        logging.getLogger("motorctl.test").warning("hello", extra={"MOTOR": 1})
        err.seek(0)
        assert err.read() == "motorctld WARNING motorctl.test: hello [MOTOR=1]\n"


def test_logging_to_the_journal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list[tuple[str, dict[str, Any]]] = []

    def send(message: str, **fields: Any) -> None:  # systemd.journal.send's signature
        sent.append((message, fields))

    fake_module(monkeypatch, "systemd.journal", send=send)
    with open(tmp_path / "err", "w") as err:
        st = os.fstat(err.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        assert service.journal_stream_is_stderr(err)
        assert service.setup_logging("info", err) == "journal"
        logging.getLogger("motorctl.test").error(
            "motor %d: E4", 2, extra={"MOTOR": 2, "COMMAND": "MoveTo", "ERROR_CODE": "E4"}
        )
    ((message, fields),) = sent
    assert message == "motor 2: E4"
    assert fields["PRIORITY"] == "3" and fields["SYSLOG_IDENTIFIER"] == "motorctld"
    assert (fields["MOTOR"], fields["COMMAND"], fields["ERROR_CODE"]) == ("2", "MoveTo", "E4")
    assert fields["LOGGER"] == "motorctl.test"


def test_journal_stream_must_be_our_stderr(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with open(tmp_path / "err", "w") as err:
        monkeypatch.setenv("JOURNAL_STREAM", "1:2")
        assert not service.journal_stream_is_stderr(err)
        monkeypatch.setenv("JOURNAL_STREAM", "garbage")
        assert not service.journal_stream_is_stderr(err)


def test_journal_handler_errors_are_handled(monkeypatch: pytest.MonkeyPatch) -> None:
    def send(message: str, **fields: Any) -> None:
        raise OSError(errno.ENOENT, "no journald")

    errors: list[logging.LogRecord] = []
    handler = service.JournalHandler(send)
    monkeypatch.setattr(handler, "handleError", errors.append)
    handler.emit(logging.LogRecord("x", logging.INFO, "f", 1, "m", None, None))
    assert len(errors) == 1


def test_time_is_bounded() -> None:
    # The fixtures above wait with deadlines; this guards the constant.
    assert 0 < DEADLINE_S <= 10 and time.monotonic() > 0


def test_motor_events_logged_off_the_step_thread(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    events = service.MotorEventLog()
    assert events.record(1, "y", "fault", "stall")
    assert not events.record(1, "y", "start", None)  # not worth a line
    assert events.record(1, "y", "cleared", None)
    assert caplog.records == []  # nothing logged by record(): no I/O on the step thread
    line = service.StatusLine(lambda: "x", send=lambda m: True, before=events.flush)
    line.update()
    fault, cleared = caplog.records
    assert fault.getMessage() == "motor 1 (y): fault latched: stall; E4 until StopMove clears it"
    assert fault.levelno == logging.ERROR
    assert (fault.MOTOR, fault.EVENT, fault.FAULT) == (1, "fault", "stall")  # type: ignore[attr-defined]
    assert cleared.getMessage() == "motor 1 (y): fault cleared"
    events.flush()
    assert len(caplog.records) == 2
    # a fault with its cause and a lost position: the figures are in the fault's text
    detail = (
        "step timing lost (step 2900 us late at 5000 step/s: lag 0.906 full steps > "
        "max_lag_full_steps 0.5 (16 microsteps, start_speed 100 step/s))"
    )
    assert events.record(0, "x", "fault", detail, "timing_lost", True)
    events.flush()
    lost = caplog.records[-1]
    assert lost.getMessage() == (
        f"motor 0 (x): fault latched: {detail}; position lost (home it "
        "again); E4 until StopMove clears it"
    )
    assert (lost.CAUSE, lost.POSITION_LOST) == ("timing_lost", 1)  # type: ignore[attr-defined]


def test_stderr_handler_follows_sys_stderr(monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    assert service.setup_logging("info") == "stderr"
    assert service.setup_logging("info") == "stderr"  # replaces its own handler, not doubled
    ours = [h for h in logging.getLogger().handlers if getattr(h, "motorctl", False)]
    assert len(ours) == 1
    later = io.StringIO()
    monkeypatch.setattr(sys, "stderr", later)  # e.g. a test runner swapping streams
    logging.getLogger("motorctl.test").info("still here")
    assert later.getvalue() == "motorctld INFO motorctl.test: still here\n"


# ------------------------------------------------------------------ the watchdog's health


def test_progress_watch_feeds_only_while_every_part_progresses() -> None:
    counters = {"link loop": 0, "step executor": 0}
    dead: dict[str, bool] = {"step executor": False}
    pokes: list[int] = []

    def probe(name: str) -> object:
        return lambda: None if dead.get(name) else counters[name]

    watch = ProgressWatch(
        {n: probe(n) for n in counters},  # type: ignore[misc]
        pokes=(lambda: pokes.append(1),),
    )
    assert watch.healthy()  # the first look has nothing to compare with
    counters["link loop"] += 1
    counters["step executor"] += 5
    assert watch.healthy() and watch.hung is None
    counters["step executor"] += 1  # the link loop did not turn
    assert not watch.healthy() and watch.hung == "link loop: no progress"
    counters["link loop"] += 1
    counters["step executor"] += 1
    assert watch.healthy() and watch.hung is None
    dead["step executor"] = True
    counters["link loop"] += 1
    assert not watch.healthy() and watch.hung == "step executor: dead"
    assert len(pokes) == 5


def test_progress_watch_idle_parts_are_healthy() -> None:
    watch = ProgressWatch({"state writer": lambda: ProgressWatch.IDLE})
    assert watch.healthy() and watch.healthy()
