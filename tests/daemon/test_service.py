"""systemd glue: notifications on a fake NOTIFY_SOCKET (built-in and via systemd.daemon),
journal logging with structured fields, the STATUS= line, the watchdog; the status socket
and the one-instance lock."""

from __future__ import annotations

import errno
import json
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
from motorctl.daemon.instance import InstanceError, InstanceLock, Owned, flock_holder
from motorctl.daemon.service import ProgressWatch
from motorctl.daemon.status import server as status_module
from motorctl.daemon.status.document import summary_line
from motorctl.daemon.status.reader import read_status
from motorctl.daemon.status.server import StatusServer, StatusSource
from tests.support.fsutil import read_only

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


# -- the status socket -----------------------------------------------------------------------
def source(doc: dict[str, Any], asked: list[bool] | None = None) -> StatusSource:
    """A status source answering ``doc`` (plus the histogram when asked); records asks."""

    def status(histogram: bool = False) -> dict[str, Any]:
        if asked is not None:
            asked.append(histogram)
        return {**doc, "histogram_us": {"0": 1}} if histogram else dict(doc)

    return status


def raw_request(path: Path, request: bytes | None) -> bytes:
    """Send ``request`` (None: nothing, then half-close) and read the answer to EOF."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(DEADLINE_S)
        sock.connect(str(path))
        if request is None:
            sock.shutdown(socket.SHUT_WR)
        else:
            sock.sendall(request)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def connect_when_there_is_room(path: Path) -> socket.socket:
    """A connected client; a full listen backlog refuses at once (EAGAIN): retry until the
    server has taken some, with a deadline."""
    deadline = time.monotonic() + DEADLINE_S
    while True:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(DEADLINE_S)
        try:
            sock.connect(str(path))
            return sock
        except BlockingIOError:
            sock.close()
            if time.monotonic() > deadline:
                raise AssertionError(f"no room in {path}'s backlog for {DEADLINE_S} s") from None
            time.sleep(0.005)


def test_status_server_serves_and_cleans_up(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"motors": []}))
    assert oct(path.stat().st_mode & 0o777) == "0o660"
    server.start()
    assert read_status(path) == {"motors": []}
    server.close()
    assert not path.exists()


def test_status_server_builds_the_histogram_only_when_asked(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    asked: list[bool] = []
    server = StatusServer(path, source({"motors": []}, asked))
    server.start()
    try:
        assert read_status(path) == {"motors": []}
        assert read_status(path, histogram=True) == {"motors": [], "histogram_us": {"0": 1}}
        assert json.loads(raw_request(path, None)) == {"motors": []}  # asked nothing: EOF
        assert asked == [False, True, False]
        bad = json.loads(raw_request(path, b"everything please\n"))
        assert "unknown status request: everything please; known: histogram" in bad["error"]
        assert "error" in json.loads(raw_request(path, b"x" * 300))  # no line end in sight
        assert asked == [False, True, False] and server.served == 5
    finally:
        server.close()


def test_status_server_a_silent_client_holds_up_nobody(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A client that connects and says nothing (or never reads) does not delay the others;
    it gets the plain status after REQUEST_WAIT_S, as ``socat - UNIX-CONNECT:`` users do.
    More silent clients than MAX_CLIENTS at once wait in the backlog and are all served."""
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"ok": True}))
    server.start()
    try:
        monkeypatch.setattr(status_module, "REQUEST_WAIT_S", 2.0)  # ample on a loaded machine
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as silent:
            silent.connect(str(path))
            t0 = time.monotonic()
            assert read_status(path) == {"ok": True}
            silent.setblocking(False)
            with pytest.raises(BlockingIOError):  # served after the other one, not before
                silent.recv(65536)
            silent.settimeout(DEADLINE_S)
            assert json.loads(silent.recv(65536)) == {"ok": True}
            assert time.monotonic() - t0 >= 2.0 * 0.9
        monkeypatch.undo()
        crowd: list[socket.socket] = []
        try:
            for _ in range(status_module.MAX_CLIENTS + 4):  # silent: each holds a slot
                crowd.append(connect_when_there_is_room(path))
            assert read_status(path) == {"ok": True}  # waits for a slot, no longer
            for sock in crowd:
                assert json.loads(sock.recv(65536)) == {"ok": True}
        finally:
            for sock in crowd:
                sock.close()
    finally:
        server.close()


def test_status_server_survives_accept_errors(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({"ok": True}))
    real = server._sock
    failures = [OSError(errno.EMFILE, "Too many open files")]

    class Flaky:
        def accept(self) -> tuple[socket.socket, Any]:
            if failures:
                raise failures.pop()
            return real.accept()

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

    server._sock = Flaky()  # type: ignore[assignment]
    server.start()
    assert read_status(path) == {"ok": True}
    assert server.errors == 1 and "accept failed" in caplog.text
    server.close()


def test_status_server_broken_status(tmp_path: Path) -> None:
    def broken(histogram: bool = False) -> dict[str, Any]:
        raise RuntimeError("boom")

    server = StatusServer(tmp_path / "s.sock", broken)
    server.start()
    assert "error" in read_status(tmp_path / "s.sock")
    server.close()


def test_status_close_leaves_a_replaced_socket_and_survives_read_only(tmp_path: Path) -> None:
    path = tmp_path / "status.sock"
    server = StatusServer(path, source({}))
    path.unlink()
    path.write_text("someone else's")
    server.close()
    assert path.read_text() == "someone else's"
    path.unlink()
    server = StatusServer(path, source({}))
    with read_only(tmp_path):
        server.close()  # cannot unlink: logged, no traceback
    assert path.exists()


def test_summary_line() -> None:
    status = {
        "motors": [
            {"index": 0, "state": "moving", "fault": None, "position_lost": False},
            {"index": 1, "state": "fault", "fault": "stall", "position_lost": True},
        ],
        "link": {"counters": {"responses": 12, "crc_errors": 1, "sent_E3": 2}},
        "state": {"ok": False, "last_error": "cannot write"},
    }
    assert summary_line(status) == (
        "2 motors: 1 moving, faulted 1, 1 to home; "
        "12 frames served, 3 errors; STATE NOT SAVED: cannot write"
    )
    assert summary_line({"motors": []}) == "0 motors: 0 moving, none faulted"


# -- one instance ---------------------------------------------------------------------------------
def test_lock_names_the_holder(tmp_path: Path) -> None:
    first = InstanceLock(tmp_path / "x.lock", "state directory X")
    first.acquire()
    assert (tmp_path / "x.lock").read_text() == f"{os.getpid()}\n"
    assert flock_holder(tmp_path / "x.lock") == os.getpid()
    second = InstanceLock(tmp_path / "x.lock", "state directory X")
    with pytest.raises(InstanceError, match=f"PID {os.getpid()}.*state directory X"):
        second.acquire()
    first.release()
    assert not (tmp_path / "x.lock").exists()
    second.acquire()
    second.release()


def test_lock_holder_from_proc_locks_when_the_file_says_nothing(tmp_path: Path) -> None:
    first = InstanceLock(tmp_path / "x.lock", "PTY")
    first.acquire()
    os.truncate(tmp_path / "x.lock", 0)
    with pytest.raises(InstanceError, match=f"PID {os.getpid()}"):
        InstanceLock(tmp_path / "x.lock", "PTY").acquire()
    first.release()
    assert flock_holder(tmp_path / "nothing") is None


def test_lock_in_unwritable_place(tmp_path: Path) -> None:
    with pytest.raises(InstanceError, match="cannot create lock file"):
        InstanceLock(tmp_path / "missing" / "x.lock", "X").acquire()


def test_owned_removes_only_its_own(tmp_path: Path) -> None:
    owned = Owned()
    owned.lock(tmp_path / "a.lock", "A")
    link = tmp_path / "pty"
    link.symlink_to("/dev/pts/999")
    owned.symlink(link, "/dev/pts/999")
    other = tmp_path / "other"
    other.symlink_to("/dev/pts/1")
    owned.symlink(other, "/dev/pts/2")  # re-pointed by someone else: theirs now
    mine = tmp_path / "mine"
    mine.write_text("x")
    owned.file(mine)
    replaced = tmp_path / "replaced"
    replaced.write_text("x")
    owned.file(replaced)
    replaced.unlink()
    replaced.write_text("new")
    plain = tmp_path / "plain"
    plain.write_text("not a link")
    owned.symlink(plain, "x")
    owned.symlink(tmp_path / "gone", "x")
    owned.cleanup()
    assert not link.is_symlink() and other.is_symlink() and not mine.exists()
    assert replaced.read_text() == "new" and plain.exists()
    assert not (tmp_path / "a.lock").exists()


def test_owned_cleanup_on_read_only_dir(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    owned = Owned()
    link = tmp_path / "pty"
    link.symlink_to("/dev/pts/999")
    owned.symlink(link, "/dev/pts/999")
    with read_only(tmp_path):
        owned.cleanup()
    assert link.is_symlink() and "cannot remove" in caplog.text


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
