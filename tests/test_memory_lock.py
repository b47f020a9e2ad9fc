"""Memory the daemon holds.

Only the step executor locks its memory (issue 7): mlockall in the daemon would lock every
thread's stack and the whole interpreter, which a 512 MB board feels. A real daemon with
``lock_memory = true`` (its default) and the ``process`` executor, no real-time priority:
the executor process has locked pages (``VmLck``), the daemon none.

A start that fails after the executor was made leaves no shared memory block behind.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

import pytest

from tests.daemon_proc import DaemonProcess, until

CONFIG = """
[step_thread]
executor = "process"
priority = 0
lock_memory = true
[[motors]]
name = "a"
"""


def locked_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmLck in /proc/{pid}/status")


def may_lock_everything() -> bool:
    """Root (CAP_IPC_LOCK) or an unlimited RLIMIT_MEMLOCK: mlockall(MCL_FUTURE) succeeds."""
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    return os.geteuid() == 0 or soft == resource.RLIM_INFINITY


@pytest.mark.skipif(not may_lock_everything(),
                    reason="mlockall needs root or an unlimited RLIMIT_MEMLOCK")
def test_only_the_step_executor_locks_its_memory(tmp_path: Path) -> None:
    daemon = DaemonProcess(tmp_path, CONFIG).start()
    try:
        status = daemon.status()
        executor = status["executor"]
        assert executor["kind"] == "process" and executor["alive"]
        pid = executor["pid"]
        assert isinstance(pid, int) and pid != daemon.proc.pid  # type: ignore[union-attr]
        until("the step executor's memory locked", lambda: locked_kb(pid) > 0)
        with daemon.client() as c:  # motion does not make the daemon lock anything
            c.move_to(0, 300)
            c.wait_moved(0, 20_000)
            assert c.position(0) == 300
        assert locked_kb(daemon.proc.pid) == 0  # type: ignore[union-attr]
        assert locked_kb(pid) > 0
    finally:
        daemon.close()


def test_a_start_that_fails_after_the_executor_was_made_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Daemon.build closes what it opened when a later part fails: here the [state]
    directory is a file, found after the step executor was made (its shared memory block
    would stay in /dev/shm until the next reboot)."""
    from motorctl.daemon import main
    from motorctl.daemon.config import parse_config

    made: list[object] = []
    real = main.build_executor

    def spy(*args: object) -> object:
        made.append(real(*args))  # type: ignore[arg-type]
        return made[-1]

    monkeypatch.setattr(main, "build_executor", spy)
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("x")
    config = parse_config(
        CONFIG.replace("lock_memory = true", "lock_memory = false")
        + f'[state]\ndirectory = "{blocker}"\n', "t.toml")
    with pytest.raises(main.StartupError, match="not-a-dir"):
        main.Daemon.build(config, tmp_path / "state", None)
    (executor,) = made
    name = executor.shm.name  # type: ignore[attr-defined]
    assert not Path("/dev/shm", name.lstrip("/")).exists()
