"""Running the daemon (daemon/start/serve.py), its parts in this process: one daemon per state
directory and PTY path, the shutdown (safe outputs, the final state written), the exit
status that says why it stopped, the executor-death watcher. The whole run, as motorctld:
test_serve_e2e.py, test_service_e2e.py."""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.errors import StartupError
from motorctl.daemon.instance import Owned
from motorctl.daemon.start import serve
from motorctl.daemon.start.assemble import ServeOptions
from motorctl.protocol.codec import SetPin
from tests.support.inprocess import build_daemon
from tests.support.wait import WAIT_S

TWO_PINS = """
[[motors]]
name = "a"
[[pins]]
number = 0
mode = "output"
initial = false
safe = false
[[pins]]
number = 1
mode = "output"
initial = false
safe = true
"""


def test_one_daemon_per_state_directory_and_pty_path(tmp_path: Path) -> None:
    config = parse_config(TWO_PINS, "t.toml")
    first, second = Owned(), Owned()
    options = ServeOptions(tmp_path / "state", pty=tmp_path / "pty")
    serve.claim(config, options, first)
    try:
        with pytest.raises(StartupError, match=f"another motorctld \\(PID {os.getpid()}\\)"):
            serve.claim(config, options, second)
        other_pty = ServeOptions(tmp_path / "other", pty=tmp_path / "pty")
        with pytest.raises(StartupError, match=f"serves the PTY {tmp_path / 'pty'}"):
            serve.claim(config, other_pty, second)
    finally:
        second.cleanup()
        first.cleanup()
    serve.claim(config, options, second)  # free again
    second.cleanup()


def test_a_state_directory_named_twice_is_locked_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--state-dir s`` and ``[state] directory = "/abs/s"`` (or ``/abs/x/../s``, or a link
    to it): one folder, one lock. Its second flock, by this very daemon, refused the start
    with 'another motorctld (PID <its own>) already serves the state directory'."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x").mkdir()
    (tmp_path / "link").symlink_to("state")
    for named in ("state", "x/../state", "link"):
        text = f'[state]\ndirectory = "{tmp_path / named}"\n{TWO_PINS}'
        config = parse_config(text, "t.toml")
        owned = Owned()
        try:
            serve.claim(config, ServeOptions(Path("state")), owned)
            assert [lock.path for lock in owned.locks] == [Path("state/motorctld.lock")]
        finally:
            owned.cleanup()
    other = parse_config(f'[state]\ndirectory = "{tmp_path / "x"}"\n{TWO_PINS}', "t.toml")
    owned = Owned()
    try:  # another folder: locked too
        serve.claim(other, ServeOptions(Path("state")), owned)
        assert len(owned.locks) == 2
    finally:
        owned.cleanup()


def test_shutdown_sets_safe_outputs_and_writes_the_final_state(tmp_path: Path) -> None:
    d = build_daemon(TWO_PINS, tmp_path)
    assert d.dispatcher.handle(SetPin(0, True)).ack
    assert [d.hw.pins[n].read() for n in (0, 1)] == [True, False]
    assert serve.shutdown(d)  # durable
    assert [d.hw.pins[n].read() for n in (0, 1)] == [False, True]  # each pin's safe level
    assert d.writer.writes >= 2 and d.writer.healthy


def stopped(died: str | None = None, saved_ok: bool = True) -> Any:
    """What exit_status reads of a daemon that stopped."""
    writer = SimpleNamespace(
        last_error=None if saved_ok else "cannot write state file /x: EROFS",
        path=Path("/x"),
        writes=3,
        errors=0 if saved_ok else 1,
    )
    return SimpleNamespace(engine=SimpleNamespace(executor_died=died), writer=writer)


def test_the_exit_status_says_why_the_daemon_stopped(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, "motorctl")
    assert serve.exit_status(stopped(), True) == 0
    assert caplog.records[-1].getMessage() == "stopped"
    assert serve.exit_status(stopped(saved_ok=False), False) == serve.EXIT_STATE_NOT_SAVED == 4
    assert "stopped WITHOUT saving the final state" in caplog.records[-1].getMessage()
    # the executor's death first: the state may be unsaved too, but that is why it stopped
    died = stopped("killed by SIGKILL", saved_ok=False)
    assert serve.exit_status(died, False) == serve.EXIT_EXECUTOR_DIED == 3
    assert "the step executor died (killed by SIGKILL)" in caplog.records[-1].getMessage()


def test_the_executor_s_death_stops_the_daemon_after_its_grace(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(serve, "EXECUTOR_DEATH_GRACE_S", 0.01)
    engine = SimpleNamespace(executor_died=None)
    stop = threading.Event()
    watcher = threading.Thread(target=serve.stop_when_executor_dies, args=(engine, stop.set))
    watcher.start()
    assert not stop.wait(0.15)  # alive: nothing happens
    engine.executor_died = "exit code -9"
    assert stop.wait(WAIT_S)
    watcher.join(WAIT_S)
    assert "the step executor died: exit code -9; stopping in 0 s" in caplog.text
