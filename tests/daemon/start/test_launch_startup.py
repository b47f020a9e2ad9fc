"""What a start of motorctld (daemon/start/launch.py, the command) does before READY: the modules it
imports (read from ``python -X importtime``, which writes each module as it is imported,
before the READY line) leave out everything a serving daemon does not need: the client, the
live monitor, the metrics, the status reader and its summary, the platform probe, the
compiled core's probe, the trace recorder and its format, and the standard library modules
only those need (a process for ``ldconfig``, temporary files, archives). And its start-up
timeline (daemon/start/timeline.py), logged at debug level, names every step of the start in order,
as bench/startup.py reads it. A real daemon on a real PTY, the embedded default."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

from motorctl.daemon.start.timeline import parse
from tests.support import REPO
from tests.support.daemon_proc import READY_TIMEOUT_S

#: never imported by a start that serves, before READY (a prefix ends in ".")
NEVER = (
    "motorctl.client.",
    "motorctl.daemon.status.monitor",
    "motorctl.daemon.status.monitor_view",
    "motorctl.daemon.status.metrics",
    "motorctl.daemon.status.metric_tables",
    "motorctl.daemon.status.reader",
    "motorctl.daemon.status.summary",
    "motorctl.daemon.start.platform_check",
    "motorctl.daemon.start.platform_kernel",
    "motorctl.daemon.config.docs",
    "motorctl.daemon.link.recorder",
    "motorctl.protocol.capture.",
    "motorctl.motion.executors.compiled_core",  # the executor's process loads the core
    "rich.",
    "prometheus_client.",
    "ctypes.util",
    "tempfile",
    "shutil",
    "platform",
    "asyncio.",
    "email.",
    "http.",
)

#: the start's steps, in order (daemon/start/serve.py and daemon/start/assemble.py mark them)
STEPS = [
    "arguments",
    "config",
    "locks",
    "hardware",
    "executor handed over",
    "state",
    "PTY",
    "link",
    "status socket",
    "executor ready",
    "threads",
]


def never(name: str) -> bool:
    return any(
        name == n.rstrip(".") or name.startswith(n if n.endswith(".") else n + ".") for n in NEVER
    )


def start_until_ready(work: Path) -> tuple[list[str], str]:
    """Start motorctld under ``-X importtime`` at debug level; at its READY line, the
    modules it has imported; then stop it: (those modules, its whole log)."""
    cmd = [
        sys.executable,
        "-X",
        "importtime",
        "-m",
        "motorctl.daemon.start.launch",
        "--pty",
        str(work / "pty"),
        "--state-dir",
        str(work / "state"),
        "--log-level",
        "debug",
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO, env=os.environ.copy()
    )
    assert proc.stdout is not None and proc.stderr is not None
    err = b""
    try:
        os.set_blocking(proc.stderr.fileno(), False)
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            sel.register(proc.stderr, selectors.EVENT_READ)
            deadline = time.monotonic() + READY_TIMEOUT_S
            out = b""
            while b"\n" not in out:
                left = deadline - time.monotonic()
                assert left > 0, f"no READY: {err.decode(errors='replace')[-2000:]}"
                for key, _ in sel.select(left):
                    chunk = os.read(key.fd, 65536)
                    if key.fileobj is proc.stdout:
                        assert chunk, f"motorctld exited: {err.decode(errors='replace')[-2000:]}"
                        out += chunk
                    else:
                        err += chunk
            assert b"motorctld ready" in out, out
            # what the daemon wrote before READY is in the pipe already
            while True:
                try:
                    chunk = os.read(proc.stderr.fileno(), 65536)
                except BlockingIOError:
                    break
                if not chunk:
                    break
                err += chunk
        at_ready = err.decode()
        proc.send_signal(signal.SIGTERM)
        os.set_blocking(proc.stderr.fileno(), True)
        err += proc.stderr.read()
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    modules = [
        line.split("|")[2].strip()
        for line in at_ready.splitlines()
        if line.startswith("import time:") and "[us]" not in line
    ]
    return modules, err.decode()


def test_a_start_imports_only_what_serving_needs_and_times_its_steps(tmp_path: Path) -> None:
    modules, log = start_until_ready(tmp_path)
    assert "motorctl.daemon.start.serve" in modules  # read as meant
    assert "motorctl.daemon.status.server" in modules
    assert sorted({m for m in modules if never(m)}) == []
    timelines = [found for line in log.splitlines() if (found := parse(line)) is not None]
    assert len(timelines) == 1, log
    first, _, steps = timelines[0]
    assert first == "imported"
    assert [step for step, _ in steps] == STEPS
    assert all(ms >= 0 for _, ms in steps)
