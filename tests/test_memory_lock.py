"""Only the step executor locks its memory (issue 7): mlockall in the daemon would lock every
thread's stack and the whole interpreter, which a 512 MB board feels.

A real daemon with ``lock_memory = true`` (its default) and the ``process`` executor, no
real-time priority: the executor process has locked pages (``VmLck``), the daemon none.
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
max_lateness_us = 10000000.0
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
