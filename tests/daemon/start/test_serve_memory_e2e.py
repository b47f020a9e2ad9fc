"""Memory a serving motorctld holds (daemon/start/serve.py runs it; a real process here).

Only the step executor locks its memory (issue 7): mlockall in the daemon would lock every
thread's stack and the whole interpreter, which a 512 MB board feels. A real daemon with
``lock_memory = true`` (its default) and the ``process`` executor, no real-time priority:
the executor process has locked pages (``VmLck``), the daemon none.

The shared memory of the daemon and its executor (the executor's block, the mock's shared
mechanics) is anonymous (memfd): no resource-tracker process runs beside them, nothing is
ever in /dev/shm, and the blocks are gone once both processes are, whichever was killed
(``kill -9`` of the daemon here, of the executor in test_serve_e2e.py); a start that fails
after the executor was made leaves no block behind either (test_assemble.py).
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

import pytest

from tests.support.daemon_proc import DaemonProcess, children_of, memfd_holders, memfd_labels
from tests.support.wait import until

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


@pytest.mark.skipif(
    not may_lock_everything(), reason="mlockall needs root or an unlimited RLIMIT_MEMLOCK"
)
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


def test_no_resource_tracker_and_no_block_left_after_a_kill_9_of_the_daemon(
    tmp_path: Path,
) -> None:
    daemon = DaemonProcess(
        tmp_path, CONFIG.replace("lock_memory = true", "lock_memory = false")
    ).start()
    try:
        assert daemon.proc is not None
        pid = daemon.proc.pid
        executor = daemon.status()["executor"]["pid"]
        assert children_of(pid) == [executor]  # no multiprocessing resource tracker
        labels = memfd_labels(pid)
        assert {label.split("-")[1] for label in labels} == {"executor", "mock"}, labels
        assert memfd_labels(executor) == labels  # both map both
        assert sorted(memfd_holders(labels)) == sorted([pid, executor])
        for p in (pid, executor):  # nothing named in /dev/shm
            assert "/dev/shm/" not in Path(f"/proc/{p}/maps").read_text()
        daemon.kill()  # SIGKILL; the executor dies with it (PR_SET_PDEATHSIG)
        until("no process holding the shared blocks", lambda: not memfd_holders(labels))
    finally:
        daemon.close()
