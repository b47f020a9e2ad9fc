"""The assembler (daemon/start/assemble.py) in this process: a start that fails closes what it
opened before (the step executor's process and shared memory, the hardware, the PTY), the
motors' events reach every served part through one listener, the geometry's fingerprint
covers what gives positions their meaning."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.errors import StartupError
from motorctl.daemon.instance import Owned
from motorctl.daemon.link import ports
from motorctl.daemon.start import assemble
from motorctl.daemon.start.assemble import Daemon, ServeOptions, build_served, motor_identities
from motorctl.daemon.start.serve import shutdown
from motorctl.motion.executors.base import Executor
from tests.support.daemon_proc import memfd_holders, step_thread_from_env
from tests.support.inprocess import IN_PROCESS_CONFIG

#: the process executor (its own process and shared memory), without real-time rights
CONFIG = """
[step_thread]
executor = "process"
priority = 0
lock_memory = false
[[motors]]
name = "a"
"""


def test_a_start_that_fails_after_the_executor_was_made_leaves_nothing_behind(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Daemon.build closes what it opened when a later part fails: here the [state]
    directory is a file, found after the step executor was made (its shared memory block
    would stay in /dev/shm until the next reboot)."""
    made: list[object] = []
    real = assemble.build_executor

    def spy(*args: object) -> object:
        made.append(real(*args))  # type: ignore[arg-type]
        return made[-1]

    monkeypatch.setattr(assemble, "build_executor", spy)
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("x")
    config = parse_config(
        CONFIG + f'[state]\ndirectory = "{blocker}"\n',
        "t.toml",
    )
    with pytest.raises(StartupError, match="not-a-dir"):
        assemble.Daemon.build(config, tmp_path / "state", None)
    (executor,) = made
    label = executor.shm.name  # type: ignore[attr-defined]
    proc = executor.proc  # type: ignore[attr-defined]
    assert proc.poll() is not None  # its process (started when it was made) is gone
    assert label.startswith("motorctl-executor-")
    assert memfd_holders({label}) == []  # unmapped and closed here, gone with the child


TWO_MOTORS = """
[[motors]]
name = "a"
max_speed = 3000.0
[[motors]]
name = "b"
max_speed = 3000.0
"""


def test_geometry_fingerprint_covers_microsteps_and_backend() -> None:
    tmc = TWO_MOTORS + "  [motors.tmc]\n  microsteps = 16\n"

    def prints(text: str) -> list[str]:
        return [i.fingerprint for i in motor_identities(parse_config(text, "t.toml"))]

    base = prints(tmc)
    assert base == prints(tmc.replace("max_speed = 3000.0\n", "max_speed = 2000.0\n"))
    assert prints(tmc.replace("microsteps = 16", "microsteps = 32"))[1] != base[1]
    assert prints(tmc.replace('name = "b"', 'name = "b"\ninvert_dir = true'))[1] != base[1]
    assert prints(tmc.replace('name = "b"', 'name = "b"\nsteps_per_rev = 200'))[1] != base[1]


def spy_executors(monkeypatch: pytest.MonkeyPatch) -> list[Executor]:
    """The step executors the assembler makes, as it makes them."""
    made: list[Executor] = []
    real = assemble.build_executor

    def spy(*args: object) -> Executor:
        made.append(real(*args))  # type: ignore[arg-type]
        return made[-1]

    monkeypatch.setattr(assemble, "build_executor", spy)
    return made


def still_open(fd: int, inode: tuple[int, int]) -> bool:
    """Whether descriptor ``fd`` still refers to the file ``inode`` (its number may have
    been reused by another file since it was closed)."""
    try:
        st = os.fstat(fd)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == inode


def test_a_served_part_that_fails_closes_everything_opened_before_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The trace is opened after the daemon and the PTY: it cannot be written, and the
    executor's process and shared memory, the hardware and the PTY are gone with the
    error (one stack of closes, each registered as its part was opened)."""
    made = spy_executors(monkeypatch)
    masters: list[tuple[int, tuple[int, int]]] = []  # each PTY master: its fd, its inode
    real_open_pty = ports.open_pty

    def open_pty(path: Path) -> tuple[int, str]:
        fd, name = real_open_pty(path)
        st = os.fstat(fd)
        masters.append((fd, (st.st_dev, st.st_ino)))
        return fd, name

    monkeypatch.setattr(assemble, "open_pty", open_pty)
    pty = tmp_path / "pty"
    options = ServeOptions(
        tmp_path / "state", pty=pty, trace=tmp_path / "no-such-folder" / "t.pcapng"
    )
    owned = Owned()
    with pytest.raises(StartupError, match="cannot write the trace file"):
        build_served(parse_config(CONFIG, "t.toml"), options, owned, None)
    (executor,) = made
    assert executor.proc.poll() is not None  # type: ignore[attr-defined]
    assert memfd_holders({executor.shm.name}) == []  # type: ignore[attr-defined]
    ((fd, inode),) = masters
    assert not still_open(fd, inode)  # the PTY's master is closed ...
    assert os.path.islink(pty)  # ... its link is Owned's to remove at exit
    assert not (tmp_path / "state" / "status.sock").exists()
    owned.cleanup()
    assert not os.path.lexists(pty)


def test_the_motors_events_reach_every_served_part_through_one_listener(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    owned = Owned()
    config = parse_config(IN_PROCESS_CONFIG, "t.toml")
    served = build_served(config, ServeOptions(tmp_path / "state", pty=tmp_path / "pty"), owned)
    daemon = served.daemon
    try:
        assert daemon.engine.listeners == [daemon._on_motor_event]  # the one listener
        assert (daemon.link, daemon.status_line, daemon.status_server) == (
            served.link,
            served.line,
            served.status,
        )
        motor = daemon.engine.motors[1]
        motor.fault = "end stop hit"
        caplog.set_level(logging.INFO, "motorctl.service")
        daemon._on_motor_event(motor, "fault")  # as the engine reports it
        assert daemon.writer.pending  # the state writer asked to write
        served.line.update()  # the STATUS= line's turn: the event logged off the step thread
        assert [r.__dict__["EVENT"] for r in caplog.records] == ["fault"]
        assert "motor 1 (b): fault latched: end stop hit" in caplog.text
    finally:
        shutdown(daemon)
        served.close()
        owned.cleanup()


def test_a_daemon_behind_the_port_has_its_listener_too(tmp_path: Path) -> None:
    daemon = Daemon.build(parse_config(IN_PROCESS_CONFIG, "t.toml"), tmp_path)
    try:
        assert daemon.engine.listeners == [daemon._on_motor_event]
        assert (daemon.link, daemon.status_line, daemon.status_server) == (None, None, None)
    finally:
        daemon.engine.executor.close()
        daemon.hw.close()


def test_the_status_lines_turn_says_what_the_error_journal_held_back(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The error answers' rate limit (daemon/refusals.py) says what it held back on the
    STATUS= line's turn, off the link thread, even when no further error comes."""
    from motorctl.daemon.refusals import BURST, EVERY_S
    from motorctl.protocol.codec import ErrorCode

    owned = Owned()
    config = parse_config(IN_PROCESS_CONFIG, "t.toml")
    served = build_served(config, ServeOptions(tmp_path / "state", pty=tmp_path / "pty"), owned)
    daemon = served.daemon
    now = [1000.0]
    refusals = daemon.dispatcher.refusals
    refusals.clock = lambda: now[0]
    try:
        caplog.set_level(logging.INFO, "motorctl.errors")
        for _ in range(BURST + 5):
            daemon.dispatcher.refused(ErrorCode.INVALID_COMMAND, "bad frame: checksum")
        served.line.update()
        assert len(caplog.records) == BURST  # nothing to say yet: the budget is spent
        now[0] += EVERY_S
        served.line.update()
        assert (
            caplog.records[-1]
            .getMessage()
            .startswith("link: 5 more error answers not logged in the last ")
        )
    finally:
        shutdown(daemon)
        served.close()
        owned.cleanup()


@pytest.mark.parametrize("kind", ["thread", "process"])
def test_lead_ms_and_ahead_ms_reach_either_step_executor(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    """[step_thread] lead_ms (how soon a re-plan may cut the running plan) and ahead_ms are
    the executor's, whichever kind the config asks for (an emulated or loaded board raises
    lead_ms: docs/timing.md)."""
    made = spy_executors(monkeypatch)
    text = CONFIG.replace(
        'executor = "process"', f'executor = "{kind}"\nlead_ms = 25\nahead_ms = 40'
    )
    daemon = Daemon.build(parse_config(text, "t.toml"), tmp_path)
    try:
        (executor,) = made
        assert (executor.lead_s, executor.ahead_s) == (0.025, 0.04)  # type: ignore[attr-defined]
    finally:
        daemon.engine.executor.close()
        daemon.hw.close()


def test_the_test_daemons_step_thread_keys_from_the_environment() -> None:
    """MOTORCTL_TEST_STEP_THREAD (the emulated lane's lead_ms = 25) parses into keys, and a
    pair without '=' is refused rather than skipped."""
    assert step_thread_from_env("") == {}
    assert step_thread_from_env("lead_ms=25, ahead_ms = 40") == {"lead_ms": "25", "ahead_ms": "40"}
    with pytest.raises(ValueError, match="lead_ms"):
        step_thread_from_env("lead_ms")
