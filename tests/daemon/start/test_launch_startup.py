"""What a start of motorctld (daemon/start/launch.py, the command) does before READY: the modules it
imports (read from ``python -X importtime``, which writes each module as it is imported,
before the READY line) leave out everything a serving daemon does not need: the client, the
live monitor, the metrics, the status reader and its summary, the platform probe, the
compiled core's probe, the trace recorder and its format, and the standard library modules
only those need (a process for ``ldconfig``, temporary files, archives). And its start-up
timeline (daemon/start/timeline.py), logged at debug level, names every step of the start in order,
as bench/startup.py reads it; every dataclass method its imports and its config step create
comes compiled from the build's file (motorctl/dataclass_code.py), as it logs. The start
runs without the garbage collector's automatic collections until READY
(daemon/start/launch.py), and the executor's process from its bootstrap's first line on,
and that process opens its step IO on the mock without the simulated driver chips
(imported where the daemon's hardware builds them). A real daemon on a real PTY, the
embedded default."""

from __future__ import annotations

import contextlib
import os
import re
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from motorctl import dataclass_code
from motorctl.daemon.start.timeline import parse
from motorctl.motion.executors.process.start import BOOTSTRAP
from tests.support import REPO
from tests.support.daemon_proc import READY_TIMEOUT_S

#: never imported by a start that serves, before READY (a prefix ends in ".")
NEVER = (
    "motorctl.client.",
    "motorctl.daemon.status.monitor",
    "motorctl.daemon.status.monitor_view",
    "motorctl.daemon.status.monitor_layout",
    "motorctl.daemon.status.monitor_parts",
    "motorctl.daemon.status.monitor_screen",
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
    # the dSPIN chips' tables: the default config names no dSPIN motor (its declaration,
    # hal/layers/dspin/config.py, checks [motors.dspin] without them)
    "motorctl.hal.dspin.chips",
    "motorctl.hal.dspin.registers",
    "motorctl.hal.dspin.status",
    "motorctl.hal.dspin.scales",
    "motorctl.hal.layers.dspin.convert",
    "fractions",
    "decimal",
    # the TMC5160's ramp generator and the TMC driver: no motor names a TMC chip (the TMC
    # layer's declaration, hal/layers/tmc/config.py, imports a chip's module when asked)
    "motorctl.hal.layers.tmc.tmc5160",
    "motorctl.hal.layers.tmc.driver",
    "motorctl.hal.layers.tmc.link",
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


def until_ready(proc: subprocess.Popen[bytes]) -> tuple[bytes, bytes]:
    """Read a starting motorctld's stdout and stderr (left non-blocking) until its READY
    line: what each had by then."""
    assert proc.stdout is not None and proc.stderr is not None
    os.set_blocking(proc.stderr.fileno(), False)
    out, err = b"", b""
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        sel.register(proc.stderr, selectors.EVENT_READ)
        deadline = time.monotonic() + READY_TIMEOUT_S
        while b"\n" not in out.partition(b"motorctld ready")[2]:
            left = deadline - time.monotonic()
            assert left > 0, f"no READY: {err.decode(errors='replace')[-2000:]}"
            for key, _ in sel.select(left):
                chunk = os.read(key.fd, 65536)
                if key.fileobj is proc.stdout:
                    assert chunk, f"motorctld exited: {err.decode(errors='replace')[-2000:]}"
                    out += chunk
                else:
                    err += chunk
    return out, err


@contextlib.contextmanager
def started_until_ready(
    cmd: list[str],
) -> Iterator[tuple[subprocess.Popen[bytes], bytes, bytes]]:
    """Start ``cmd`` (a serving motorctld) with its stdout and stderr piped, and read both
    to its READY line: the process, what each had by then; killed if still running and its
    pipes closed at the end."""
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO, env=os.environ.copy()
    )
    assert proc.stdout is not None and proc.stderr is not None
    try:
        yield (proc, *until_ready(proc))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


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
    with started_until_ready(cmd) as (proc, _, err):
        assert proc.stderr is not None
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
    # its modules and its config's declarations took every dataclass method's code from the
    # build's file (motorctl/dataclass_code.py): none compiled
    said = [line for line in log.splitlines() if "dataclass code: " in line]
    assert len(said) == 1 and "WARNING" not in said[0], said
    counts = re.search(r"dataclass code: (\d+) methods from (\S+), (\d+) compiled$", said[0])
    assert counts is not None, said
    # Python 3.11 and 3.12 compile each method alone, 3.13 all of a class's together
    least = 300 if sys.version_info < (3, 13) else 100
    assert int(counts[1]) > least and counts[2] == str(dataclass_code.default_path())
    assert counts[3] == "0", f"{said[0]}: run make dataclass-code"


#: run before motorctld's own code (``python -c``): every collection the collector starts
#: once launch.py has decided to serve (it imports process.start right after), on stdout
#: before the READY line: "gc GENERATION"
COUNT_COLLECTIONS = """\
import gc, runpy, sys
def seen(phase, info):
    if phase == "start" and "motorctl.motion.executors.process.start" in sys.modules:
        sys.stdout.write(f"gc {info['generation']}\\n")
gc.callbacks.append(seen)
runpy.run_module("motorctl.daemon.start.launch", run_name="__main__", alter_sys=True)
"""


def output_around_ready(cmd: list[str]) -> tuple[list[str], list[str]]:
    """Start ``cmd`` (a serving motorctld), stop it once its READY line came (SIGTERM: it
    exits 0): its stdout's lines before READY and after."""
    with started_until_ready(cmd) as (proc, out, _):
        assert proc.stdout is not None and proc.stderr is not None
        os.set_blocking(proc.stderr.fileno(), True)
        proc.send_signal(signal.SIGTERM)
        out += proc.stdout.read()  # what it wrote after READY, flushed at its exit
        assert proc.wait(20) == 0, proc.stderr.read().decode()[-2000:]
    before, _, after = out.decode().partition("motorctld ready")
    return before.splitlines(), after.splitlines()[1:]


def test_a_start_runs_without_automatic_collections_until_ready(tmp_path: Path) -> None:
    cmd = [sys.executable, "-c", COUNT_COLLECTIONS, "--pty", str(tmp_path / "pty")]
    before, after = output_around_ready([*cmd, "--state-dir", str(tmp_path / "state")])
    assert "gc 2" in after  # the collection after READY (rt.GcPolicy.ready): counted
    # with the collector on: dozens, while the daemon imports its modules
    assert [line for line in before if line.startswith("gc ")] == []


def test_the_executors_bootstrap_turns_automatic_collection_off_first() -> None:
    code = BOOTSTRAP.splitlines()
    statements = [line for line in code if line.strip() and not line.startswith("#")]
    assert statements[:2] == ["import gc", "gc.disable()  # " + statements[1].split("# ")[1]]


#: the simulated driver chips (hal/backends/mock/dspin_world.py imports them when it builds
#: a world's chains): the daemon's hardware has them, the executor's step IO not
DSPIN_SIMULATION = (
    "motorctl.hal.backends.mock.dspin_chain",
    "motorctl.hal.backends.mock.dspin_chip",
    "motorctl.hal.backends.mock.dspin_motion",
    "fractions",
)

#: in a fresh interpreter: the default config's spec, then the executor process's step IO
#: opened on it as child.py opens it; the modules that opening imported
STEP_IO_IMPORTS = """\
import sys
from motorctl.daemon.config import load_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.interfaces import MonotonicClock
from motorctl.hal.registry import open_step_io
spec = hardware_spec(load_config(None))
before = set(sys.modules)
io = open_step_io("mock", spec, MonotonicClock(), None)
print(len(io.endstops))
io.close()
print(" ".join(sorted(set(sys.modules) - before)))
"""


def test_the_executors_step_io_on_the_mock_imports_no_simulated_chips() -> None:
    out = subprocess.run(
        [sys.executable, "-c", STEP_IO_IMPORTS],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
        timeout=60,
    ).stdout.splitlines()
    assert out[0] == "3"  # the default's three motors' step IO, read as meant
    imported = out[1].split()
    assert "motorctl.hal.backends.mock.world" in imported
    assert [m for m in imported if m in DSPIN_SIMULATION] == []
