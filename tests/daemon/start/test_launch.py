"""The motorctld command (daemon/start/launch.py) starts the step executor's interpreter before
the daemon's imports (motion/executors/process/start.py): the process executor takes it over;
any other outcome ends it, also when the daemon fails to start or is gone before handing it its
parameters. Real processes throughout."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from motorctl.daemon.start import launch
from motorctl.motion.executors.process.start import WaitingInterpreter
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess, children_of
from tests.support.wait import until

REPO = REPO


@pytest.mark.parametrize(
    ("argv", "serves"),
    [
        (["--pty", "x"], True),
        (["--port=/dev/ttyAMA0", "--config", "c.toml"], True),
        (["--pty", "x", "--check-config", "c.toml"], False),
        (["--status"], False),
        (["--pty", "x", "--version"], False),
        (["--config", "c.toml"], False),
    ],
)
def test_only_a_command_line_that_serves_gets_the_head_start(argv: list[str], serves: bool) -> None:
    assert launch.serves(argv) is serves


def test_the_process_executor_takes_the_early_process_over(tmp_path: Path) -> None:
    d = DaemonProcess(tmp_path).start()  # python -m motorctl.daemon.start.launch
    try:
        assert d.proc is not None
        executor = d.status()["executor"]
        assert executor["kind"] == "process" and executor["alive"]
        assert children_of(d.proc.pid) == [executor["pid"]]  # the early one, no second
        with d.client() as c:
            c.move_to(0, 100)
            c.wait_moved(0, 10_000)
            assert c.position(0) == 100
    finally:
        d.close()


def test_a_daemon_that_fails_to_start_ends_the_early_process(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    started: list[WaitingInterpreter] = []
    real = WaitingInterpreter.start

    def spy() -> WaitingInterpreter:
        started.append(real())
        return started[-1]

    monkeypatch.setattr(WaitingInterpreter, "start", spy)
    argv = [
        "--pty",
        str(tmp_path / "pty"),
        "--state-dir",
        str(tmp_path / "state"),
        "--config",
        str(tmp_path / "missing.toml"),
    ]
    assert launch.main(argv) == 1
    assert "missing.toml" in capsys.readouterr().err
    (early,) = started
    assert not early.waiting and early.proc.poll() is not None  # ended and reaped


def test_the_early_process_ends_by_itself_when_the_daemon_is_gone() -> None:
    """A daemon that dies before handing its parameters over (kill -9 during start-up):
    the process sees its socket end and exits 0, holding nothing."""
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "from motorctl.motion.executors.process.start import WaitingInterpreter; "
            "print(WaitingInterpreter.start().pid)",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        check=True,
    )
    pid = int(out.stdout)

    def gone() -> bool:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except FileNotFoundError:
            return True
        return state == "Z"  # exited; its new parent has not reaped it (yet)

    until(f"the orphaned executor process {pid} to exit", gone)
