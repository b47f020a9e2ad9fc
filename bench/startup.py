"""motorctld's start-up: time to READY against a bare interpreter, where it goes, the
processes it runs and the memory they hold.

Each run starts motorctld on the embedded default (the mock world, the ``process`` step
executor, its default real-time settings) on a PTY in a fresh state directory (on a tmpfs
where there is one, /dev/shm, as /run/motorctl is under systemd: ``--state-on disk`` puts it
in the temporary folder instead), times it from the start of the process to its READY line
(printed right before systemd's READY=1) and reads the CPU time the daemon and its executor
process had used by then (/proc/PID/stat); then, half a second later, records every process
it runs (no multiprocessing resource tracker: its shared memory is anonymous), their RSS and
PSS (/proc/PID/smaps_rollup: shared pages counted once), the executor's locked memory, and
whether anything is mapped from /dev/shm; then SIGTERM, and the next run.

Its ratio to a bare interpreter (``python -c pass``, started the same way, one before each
run: the same load for both) is the figure to judge: the median READY over the median bare
start, in the same run. Beside it, the CPU ratio: the daemon's CPU time by READY over the
bare interpreter's (medians), steadier than the wall clock on a shared machine, where the
executor's interpreter and other work take the second CPU from the daemon.

The breakdown comes from the daemon's own start-up timeline (daemon/start/timeline.py: run with
``--log-level debug``, it logs when each step of its start ended, on the monotonic clock this
benchmark reads too): "interpreter and imports" from the process's start until the daemon's
modules are imported (of which a bare interpreter's start is the first part), then the
command line, the config, the locks, the hardware, the step executor's process handed its
parameters, the state restored and written, the PTY, the link, the status socket, the
executor ready (its process's own start runs beside the daemon's: this is what was left to
wait for), the threads started, and the READY line's way to this process.

Two ways to start it, in alternate runs (the same load for both):

  motorctld   python -m motorctl.daemon.start.launch, the ``motorctld`` command: the executor's
              interpreter starts first, beside the daemon's imports (daemon/start/launch.py)
  main        python -m motorctl.daemon.start.main: the same daemon, the executor started when
              the config has been read

and two states of the bytecode cache:

  cached      every module's bytecode cached, as the Debian package (compiled at install)
              or a checkout used before give it: a temporary PYTHONPYCACHEPREFIX, filled by
              a first start that is not counted
  sources     motorctl's own modules compiled at every start (PYTHONDONTWRITEBYTECODE=1
              and no __pycache__ in the checkout, as on this project's shared machines; the
              standard library's bytecode is cached)

Targets: READY within 2x a bare interpreter's start (issue 36), <= 200 ms (issue 16), no
resource tracker, all processes' RSS <= 60 MB. Timing on a shared machine is noisy: the
minimum shows what the code costs, the median what the machine gave it; the CPU times are
steadier than the wall clock under load. ``--json FILE`` writes every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import selectors
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motorctl.daemon.start.timeline import parse  # noqa: E402  (the daemon's start-up line)

ENTRIES = {"motorctld": "motorctl.daemon.start.launch", "main": "motorctl.daemon.start.main"}
READY_TARGET_MS = 200.0
RATIO_TARGET = 2.0
RSS_TARGET_MIB = 60.0
SETTLE_S = 0.5
TIMEOUT_S = 30.0

#: The least a daemon of this design imports, whatever its own code: its records
#: (``dataclasses``, which brings ``inspect``, ``enum`` and ``re``), its interfaces
#: (``typing``'s Protocol), the journal (``logging``), the status socket and systemd's
#: notification (``socket``), the status documents and the state file (``json``), the
#: config (``tomllib``), its threads, the link's ``poll``, signals, and the frames'
#: ``struct``. A start cannot come nearer a bare interpreter's than these imports do.
LEAST = (
    "dataclasses",
    "enum",
    "typing",
    "logging",
    "socket",
    "json",
    "tomllib",
    "threading",
    "select",
    "signal",
    "struct",
)


def status_kib(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0


def pss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Pss:"):
            return int(line.split()[1])
    return 0


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, their children, ...)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        found += kids
        todo += kids
    return sorted(found)


def cmdline(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()


def cpu_ms(pid: int) -> float:
    """User + system CPU time process ``pid`` has used (its threads; not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * 1000 / os.sysconf("SC_CLK_TCK")


def breakdown(stderr: str, t0: float, ready: float) -> dict[str, float]:
    """The start's steps in ms, in order, from the daemon's start-up line in ``stderr``;
    ``t0``, ``ready``: when the process was started and its READY line came (monotonic).
    Empty without that line (a motorctl from before it)."""
    found = None
    for line in stderr.splitlines():
        found = parse(line) or found
    if found is None:
        return {}
    _, imported, steps = found
    out = {"interpreter and imports": (imported - t0) * 1000}
    for step, ms in steps:
        out[step] = out.get(step, 0.0) + ms
    out["READY line"] = (ready - imported) * 1000 - sum(ms for _, ms in steps)
    return out


def one_start(
    module: str, env: dict[str, str], work: Path, state: Path, xopts: Sequence[str] = ()
) -> dict[str, Any]:
    """Start motorctld, time READY, look at its processes, stop it (state in ``state``;
    ``xopts``: the interpreter's options, before ``-m``)."""
    work.mkdir()
    cmd = [
        sys.executable,
        *xopts,
        "-m",
        module,
        "--pty",
        str(work / "pty"),
        "--state-dir",
        str(state),
        "--log-level",
        "debug",  # its start-up timeline
    ]
    with open(work / "stderr", "wb") as err:
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, env=env, cwd=ROOT)
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    line = b""
    try:
        while not line.endswith(b"\n"):
            left = t0 + TIMEOUT_S - time.monotonic()
            if left <= 0 or not sel.select(left):
                raise RuntimeError(
                    f"no READY within {TIMEOUT_S} s: {(work / 'stderr').read_text()}"
                )
            chunk = os.read(proc.stdout.fileno(), 1)
            if not chunk:
                raise RuntimeError(f"motorctld exited: {(work / 'stderr').read_text()}")
            line += chunk
        ready = time.monotonic()
        kids = descendants(proc.pid)
        cpu = {"daemon": cpu_ms(proc.pid), "executor": sum(cpu_ms(p) for p in kids)}
        if b"motorctld ready" not in line:
            raise RuntimeError(f"not the READY line: {line!r}")
        time.sleep(SETTLE_S)
        kids = descendants(proc.pid)
        pids = [proc.pid, *kids]
        names = {pid: cmdline(pid) for pid in kids}
        executors = [pid for pid, name in names.items() if "resource_tracker" not in name]
        maps = "".join(Path(f"/proc/{pid}/maps").read_text() for pid in pids)
        out = {
            "ready_ms": round((ready - t0) * 1000, 1),
            "cpu_ms_at_ready": cpu,
            "steps_ms": breakdown((work / "stderr").read_text(), t0, ready),
            "processes": len(pids),
            "resource_tracker": any("resource_tracker" in name for name in names.values()),
            "dev_shm_mappings": maps.count("/dev/shm/"),
            "rss_kib": {
                "daemon": status_kib(proc.pid, "VmRSS"),
                "executor": sum(status_kib(p, "VmRSS") for p in executors),
                "total": sum(status_kib(p, "VmRSS") for p in pids),
            },
            "pss_kib_total": sum(pss_kib(p) for p in pids),
            "executor_locked_kib": sum(status_kib(p, "VmLck") for p in executors),
            "executor_fifo": any(os.sched_getscheduler(p) == os.SCHED_FIFO for p in executors),
        }
    finally:
        sel.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        proc.stdout.close()
    return out


def bare_interpreter(env: dict[str, str], code: str = "pass") -> tuple[float, float]:
    """A bare interpreter's start, ``python -c pass`` as motorctld is started (the same
    interpreter, folder and environment), or one that runs ``code`` (a floor's imports):
    (wall ms, CPU ms)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = (time.monotonic() - t0) * 1000
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"python -c {code[:60]!r} exited {proc.returncode}")
    return wall, (usage.ru_utime + usage.ru_stime) * 1000


def imports_code(modules: Sequence[str]) -> str:
    """A program that imports ``modules`` (each that this interpreter has: a start tries
    some that only another platform has, ``_winapi``, and goes on without them)."""
    lines = ["import importlib", "for name in ("]
    lines += [f"    {name!r}," for name in modules]
    lines += ["):", "    try:", "        importlib.import_module(name)", "    except ImportError:"]
    return "\n".join([*lines, "        pass"])


def imported_outside(env: dict[str, str], work: Path, state: Path) -> list[str]:
    """The modules from outside motorctl that motorctld's start imports by READY (the
    standard library's, pyserial's, ...): one start, not counted, under ``-X importtime``
    (which lists every import the daemon's interpreter made, the executor's not)."""
    one_start(ENTRIES["motorctld"], env, work, state, xopts=("-X", "importtime"))
    names: list[str] = []
    for line in (work / "stderr").read_text().splitlines():
        if line.startswith("import time:") and "[us]" not in line:
            name = line.rsplit("|", 1)[1].strip()
            if name.split(".")[0] != "motorctl" and not name.startswith("__editable__"):
                names.append(name)
    return list(dict.fromkeys(names))


def spread(values: list[float]) -> dict[str, float]:
    return {
        "min": round(min(values), 1),
        "median": round(statistics.median(values), 1),
        "max": round(max(values), 1),
    }


def checkout_has_bytecode() -> bool:
    """Whether motorctl's modules have bytecode beside them (then 'sources' is not cold)."""
    return any(ROOT.glob("*/__pycache__/*.pyc"))


def state_folder(where: str, tmpdir: Path) -> Path:
    """Where the runs' state directories go: a tmpfs (/dev/shm, as /run/motorctl is under
    systemd) for ``tmpfs`` where there is one, else the temporary folder (``disk``)."""
    if where == "tmpfs" and Path("/dev/shm").is_dir() and os.access("/dev/shm", os.W_OK):
        return Path(tempfile.mkdtemp(prefix="motorctl-startup-state-", dir="/dev/shm"))
    return tmpdir / "states"


def figures(runs_of: list[dict[str, Any]], bare: dict[str, list[float]]) -> dict[str, Any]:
    """One entry's figures over its runs, with its ratio to the bare interpreter's."""
    last = runs_of[-1]
    ready = [r["ready_ms"] for r in runs_of]
    cpu = {k: [r["cpu_ms_at_ready"][k] for r in runs_of] for k in ("daemon", "executor")}
    return {
        "ready_ms": spread(ready),
        "ratio_to_bare": round(statistics.median(ready) / statistics.median(bare["wall"]), 2),
        "ratio_to_bare_min": round(min(ready) / min(bare["wall"]), 2),
        "cpu_ratio_to_bare": round(
            statistics.median(cpu["daemon"]) / statistics.median(bare["cpu"]), 2
        ),
        "cpu_ms_at_ready": {k: spread(v) for k, v in cpu.items()},
        "steps_ms": {
            step: round(statistics.median(r["steps_ms"].get(step, 0.0) for r in timed), 1)
            # in the daemon's order, as its start-up line gives them (breakdown keeps it)
            for step in dict.fromkeys(s for r in timed for s in r["steps_ms"])
        }
        if (timed := [r for r in runs_of if r["steps_ms"]])
        else {},
        "processes": last["processes"],
        "resource_tracker": any(r["resource_tracker"] for r in runs_of),
        "dev_shm_mappings": max(r["dev_shm_mappings"] for r in runs_of),
        "rss_mib": {
            k: round(statistics.median(r["rss_kib"][k] for r in runs_of) / 1024, 1)
            for k in ("daemon", "executor", "total")
        },
        "pss_mib_total": round(statistics.median(r["pss_kib_total"] for r in runs_of) / 1024, 1),
        "executor_locked_mib": round(last["executor_locked_kib"] / 1024, 1),
        "executor_fifo": last["executor_fifo"],
    }


def measure(runs: int, modes: list[str], entries: list[str], state_on: str) -> dict[str, Any]:
    base = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX", "NOTIFY_SOCKET")
    }
    result: dict[str, Any] = {
        "python": sys.executable,
        "python_version": sys.version.split()[0],
        "cpus": len(os.sched_getaffinity(0)),
        "load_before": os.getloadavg()[0],
        "runs": runs,
        "targets": {
            "ratio_to_bare": RATIO_TARGET,
            "ready_ms": READY_TARGET_MS,
            "rss_mib": RSS_TARGET_MIB,
        },
        "modes": {},
    }
    with tempfile.TemporaryDirectory(prefix="motorctl-startup-") as tmp:
        tmpdir = Path(tmp)
        states = state_folder(state_on, tmpdir)
        result["state_dirs_in"] = str(states.parent if state_on == "tmpfs" else states)
        outside: list[str] = []
        try:
            for mode in modes:
                env = dict(base)
                if mode == "cached":
                    env["PYTHONPYCACHEPREFIX"] = str(tmpdir / "pycache")
                    # fills the cache (and the bare interpreter's)
                    one_start(ENTRIES[entries[0]], env, tmpdir / "warm-up", states / "warm-up")
                    bare_interpreter(env)
                else:
                    env["PYTHONDONTWRITEBYTECODE"] = "1"
                if not outside:
                    outside = imported_outside(env, tmpdir / "importtime", states / "importtime")
                    result["imported_outside"] = outside
                floors = {"least": imports_code(LEAST), "outside": imports_code(outside)}
                samples: dict[str, list[dict[str, Any]]] = {e: [] for e in entries}
                bare: dict[str, list[float]] = {"wall": [], "cpu": []}
                floor: dict[str, list[float]] = {name: [] for name in floors}
                for i in range(runs):
                    wall, cpu = bare_interpreter(env)  # interleaved: the same load for all
                    bare["wall"].append(wall)
                    bare["cpu"].append(cpu)
                    for name, code in floors.items():
                        floor[name].append(bare_interpreter(env, code)[0])
                    for entry in entries:
                        name = f"{mode}-{entry}-{i}"
                        samples[entry].append(
                            one_start(ENTRIES[entry], env, tmpdir / name, states / name)
                        )
                fig: dict[str, Any] = {
                    "bare_interpreter_ms": spread(bare["wall"]),
                    "bare_interpreter_cpu_ms": spread(bare["cpu"]),
                    "floors": {
                        name: {
                            "ms": spread(walls),
                            "ratio_to_bare": round(
                                statistics.median(walls) / statistics.median(bare["wall"]), 2
                            ),
                        }
                        for name, walls in floor.items()
                    },
                }
                if mode == "sources":
                    fig["checkout_has_bytecode"] = checkout_has_bytecode()
                for entry, runs_of in samples.items():
                    fig[entry] = figures(runs_of, bare)
                result["modes"][mode] = fig
        finally:
            if state_on == "tmpfs" and states.parent != tmpdir:
                shutil.rmtree(states, ignore_errors=True)
    result["load_after"] = os.getloadavg()[0]
    return result


def report(result: dict[str, Any]) -> None:
    print(
        f"motorctld start-up, {result['runs']} runs each ({result['python']} "
        f"{result['python_version']}, {result['cpus']} CPUs, load "
        f"{result['load_before']:.2f} -> {result['load_after']:.2f}; state directories in "
        f"{result['state_dirs_in']}):"
    )
    for mode, fig in result["modes"].items():
        bare, bare_cpu = fig["bare_interpreter_ms"], fig["bare_interpreter_cpu_ms"]
        print(
            f"  bytecode {mode}: a bare interpreter {bare['median']} ms (min {bare['min']}; "
            f"CPU {bare_cpu['median']} ms)"
            + (
                "; NOTE: the checkout has __pycache__, so this is not cold"
                if fig.get("checkout_has_bytecode")
                else ""
            )
        )
        least, outside = fig["floors"]["least"], fig["floors"]["outside"]
        print(
            f"    floors: the least a daemon like this imports ({', '.join(LEAST)}) "
            f"{least['ms']['median']} ms, {least['ratio_to_bare']:.2f}x the bare interpreter; "
            f"the {len(result['imported_outside'])} modules from outside motorctl that a start "
            f"imports {outside['ms']['median']} ms, {outside['ratio_to_bare']:.2f}x"
        )
        for entry in ENTRIES:
            if entry not in fig:
                continue
            f = fig[entry]
            r, rss, cpu = f["ready_ms"], f["rss_mib"], f["cpu_ms_at_ready"]
            print(
                f"    {entry:9s} READY median {r['median']:6.1f} ms (min {r['min']:.1f}, "
                f"max {r['max']:.1f}): {f['ratio_to_bare']:.2f}x the bare interpreter "
                f"(min to min {f['ratio_to_bare_min']:.2f}x); CPU by READY: daemon "
                f"{cpu['daemon']['median']:.0f} ms ({f['cpu_ratio_to_bare']:.2f}x the bare "
                f"interpreter's), executor {cpu['executor']['median']:.0f} ms"
            )
            steps = f["steps_ms"]
            print(
                "      where it goes (medians, ms): "
                + (
                    ", ".join(f"{step} {ms:.1f}" for step, ms in steps.items())
                    if steps
                    else "not known (the daemon logged no start-up timeline)"
                )
            )
            print(
                f"      {f['processes']} processes, resource tracker "
                f"{'YES' if f['resource_tracker'] else 'no'}, /dev/shm mappings "
                f"{f['dev_shm_mappings']}; RSS daemon {rss['daemon']} + executor "
                f"{rss['executor']} = {rss['total']} MiB (PSS {f['pss_mib_total']} MiB; "
                f"executor locks {f['executor_locked_mib']} MiB, SCHED_FIFO "
                f"{'yes' if f['executor_fifo'] else 'no'})"
            )
    print(
        f"  targets: READY within {RATIO_TARGET:.0f}x a bare interpreter's start and <= "
        f"{READY_TARGET_MS:.0f} ms, no resource tracker, RSS <= {RSS_TARGET_MIB:.0f} MiB"
    )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=10, help="starts of each kind (default 10)")
    ap.add_argument("--bytecode", choices=("cached", "sources", "both"), default="both")
    ap.add_argument(
        "--entry",
        choices=(*ENTRIES, "both"),
        default="both",
        help="motorctld (the command), main (python -m motorctl.daemon.start.main)",
    )
    ap.add_argument(
        "--state-on",
        choices=("tmpfs", "disk"),
        default="tmpfs",
        help="where the state directories go: a tmpfs (/dev/shm), as /run/motorctl under "
        "systemd (default), or the temporary folder",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args()
    modes = ["cached", "sources"] if args.bytecode == "both" else [args.bytecode]
    entries = list(ENTRIES) if args.entry == "both" else [args.entry]
    result = measure(args.runs, modes, entries, args.state_on)
    report(result)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
