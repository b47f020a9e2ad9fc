"""Real time that says what it got, end to end (daemon/start/serve.py's READY line, and the status
of what it serves): motorctld under limits that make the kernel refuse its executor
SCHED_FIFO and mlockall, for real (no root real time is needed: the refusal is the test),
says so in its READY line, its status document, systemd's STATUS= summary and
``motorctld --status`` on a terminal, each refusal with its reason and its fix; the README's
quoted READY line has the fields a real one has."""

from __future__ import annotations

import os
import re
import sys

from motorctl.daemon.status.document import summary_line
from tests.support import REPO
from tests.support.daemon_proc import StartDaemon, run_on_pty, without_real_time

#: asks for what the embedded default asks for (test daemons otherwise ask for nothing)
ASKING = """
[step_thread]
executor = "process"
priority = 50
lock_memory = true

[[motors]]
name = "a"
"""


def test_real_time_the_kernel_refuses_is_said_everywhere(motorctld: StartDaemon) -> None:
    d = motorctld(ASKING, prefix=without_real_time())
    ready = d.ready_line.rstrip()
    assert "; real time SCHED_FIFO 50 REFUSED (EPERM), mlockall REFUSED (ENOMEM), " in ready
    assert ready.endswith(": steps best effort, 'motorctld --status' says why and the fix")
    doc = d.status()
    rt = doc["executor"]["realtime"]
    assert rt["refused"] == ["memory_lock", "sched_fifo"]
    assert rt["sched_fifo"]["reason"] == (
        "EPERM (Operation not permitted): RLIMIT_RTPRIO is 0, below 50, and the process "
        "lacks CAP_SYS_NICE"
    )
    assert "LimitRTPRIO=50 or more" in rt["sched_fifo"]["fix"]
    assert rt["memory_lock"]["error"] == "ENOMEM" and "LimitMEMLOCK" in rt["memory_lock"]["fix"]
    pid = doc["executor"]["pid"]
    assert os.sched_getscheduler(pid) == os.SCHED_OTHER  # what the kernel left it
    assert "; REAL TIME REFUSED (mlockall, SCHED_FIFO 50): steps best effort" in (summary_line(doc))
    main = [sys.executable, "-m", "motorctl.daemon.start.main"]
    code, out = run_on_pty([*main, "--status", "--state-dir", str(d.state_dir)])
    assert code == 0, out
    lines = out.splitlines()
    at = lines.index("real time: REFUSED, steps best effort")
    assert lines[at + 1].startswith("  SCHED_FIFO 50 REFUSED: EPERM (Operation not permitted):")
    fixes = [i for i, line in enumerate(lines) if line.startswith("    fix: run it as root")]
    memory = next(i for i, line in enumerate(lines) if line.startswith("  mlockall REFUSED:"))
    assert len(fixes) == 2 and at < fixes[0] < memory < fixes[1]  # each with its fix
    assert lines[memory].startswith("  mlockall REFUSED: ENOMEM (Cannot allocate memory)")


def test_the_readmes_ready_line_has_the_fields_of_a_real_one(motorctld: StartDaemon) -> None:
    """The README quotes what ``make run`` prints: the same fields, in the same order, each
    beginning with the same words as a real daemon's."""
    readme = (REPO / "README.md").read_text()
    quoted = next(line for line in readme.splitlines() if line.startswith("motorctld ready: "))
    real = motorctld().ready_line.strip()

    def heads(line: str) -> list[str]:
        # each field's first word or two: "serving", "config", "3 motors" -> "motors", ...
        return [re.sub(r"^\d+ ", "", f).split(" ")[0] for f in line.split("; ")]

    assert heads(quoted) == heads(real), (quoted, real)
    assert quoted.split("; ")[-1].startswith("real time ")
