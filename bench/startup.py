"""motorctld's start-up: time to READY, the processes it runs and the memory they hold.

Each run starts motorctld on the embedded default (the mock world, the ``process`` step
executor, its default real-time settings) on a PTY in a fresh state directory, times it from
the start of the process to its READY line (printed right before systemd's READY=1), then,
half a second later, records every process it runs (no multiprocessing resource tracker: its
shared memory is anonymous), their RSS and PSS (/proc/PID/smaps_rollup: shared pages counted
once), the executor's locked memory, and whether anything is mapped from /dev/shm; then
SIGTERM, and the next run.

Two ways to start it, in alternate runs (the same load for both):

  motorctld   python -m motorctl.daemon.launch, the ``motorctld`` command: the executor's
              interpreter starts first, beside the daemon's imports (daemon/launch.py)
  main        python -m motorctl.daemon.main: the same daemon, the executor started when
              the config has been read

and two states of the bytecode cache:

  cached      every module's bytecode cached, as the Debian package (compiled at install)
              or a checkout used before give it: a temporary PYTHONPYCACHEPREFIX, filled by
              a first start that is not counted
  sources     motorctl's own modules compiled at every start (PYTHONDONTWRITEBYTECODE=1
              and no __pycache__ in the checkout, as on this project's shared machines; the
              standard library's bytecode is cached)

For reference, a bare interpreter (``python -c pass``). Targets (issue 16): READY <= 200 ms,
no resource tracker, all processes' RSS <= 60 MB. Timing on a shared machine is noisy: the
minimum shows what the code costs, the median what the machine gave it.
``--json FILE`` writes every figure.
"""

from __future__ import annotations

import argparse
import json
import os
import selectors
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ENTRIES = {"motorctld": "motorctl.daemon.launch", "main": "motorctl.daemon.main"}
READY_TARGET_MS = 200.0
RSS_TARGET_MIB = 60.0
SETTLE_S = 0.5
TIMEOUT_S = 30.0


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


def one_start(module: str, env: dict[str, str], work: Path) -> dict[str, Any]:
    """Start motorctld, time READY, look at its processes, stop it."""
    work.mkdir()
    cmd = [
        sys.executable,
        "-m",
        module,
        "--pty",
        str(work / "pty"),
        "--state-dir",
        str(work / "state"),
        "--log-level",
        "warning",
    ]
    with open(work / "stderr", "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, env=env, cwd=ROOT)
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    line = b""
    try:
        while not line.endswith(b"\n"):
            left = t0 + TIMEOUT_S - time.perf_counter()
            if left <= 0 or not sel.select(left):
                raise RuntimeError(
                    f"no READY within {TIMEOUT_S} s: {(work / 'stderr').read_text()}"
                )
            chunk = os.read(proc.stdout.fileno(), 1)
            if not chunk:
                raise RuntimeError(f"motorctld exited: {(work / 'stderr').read_text()}")
            line += chunk
        ready_ms = (time.perf_counter() - t0) * 1000
        if b"motorctld ready" not in line:
            raise RuntimeError(f"not the READY line: {line!r}")
        time.sleep(SETTLE_S)
        kids = descendants(proc.pid)
        pids = [proc.pid, *kids]
        names = {pid: cmdline(pid) for pid in kids}
        executors = [pid for pid, name in names.items() if "resource_tracker" not in name]
        maps = "".join(Path(f"/proc/{pid}/maps").read_text() for pid in pids)
        out = {
            "ready_ms": round(ready_ms, 1),
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


def bare_interpreter_ms(runs: int, env: dict[str, str]) -> list[float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], env=env, check=True)
        times.append((time.perf_counter() - t0) * 1000)
    return times


def spread(values: list[float]) -> dict[str, float]:
    return {
        "min": round(min(values), 1),
        "median": round(statistics.median(values), 1),
        "max": round(max(values), 1),
    }


def checkout_has_bytecode() -> bool:
    """Whether motorctl's modules have bytecode beside them (then 'sources' is not cold)."""
    return any(ROOT.glob("*/__pycache__/*.pyc"))


def measure(runs: int, modes: list[str], entries: list[str]) -> dict[str, Any]:
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
        "targets": {"ready_ms": READY_TARGET_MS, "rss_mib": RSS_TARGET_MIB},
        "modes": {},
    }
    with tempfile.TemporaryDirectory(prefix="motorctl-startup-") as tmp:
        tmpdir = Path(tmp)
        for mode in modes:
            env = dict(base)
            if mode == "cached":
                env["PYTHONPYCACHEPREFIX"] = str(tmpdir / "pycache")
                one_start(ENTRIES[entries[0]], env, tmpdir / "warm-up")  # fills the cache
            else:
                env["PYTHONDONTWRITEBYTECODE"] = "1"
            samples: dict[str, list[dict[str, Any]]] = {e: [] for e in entries}
            for i in range(runs):
                for entry in entries:  # alternate: both see the same load
                    samples[entry].append(
                        one_start(ENTRIES[entry], env, tmpdir / f"{mode}-{entry}-{i}")
                    )
            fig: dict[str, Any] = {"bare_interpreter_ms": spread(bare_interpreter_ms(runs, env))}
            if mode == "sources":
                fig["checkout_has_bytecode"] = checkout_has_bytecode()
            for entry, runs_of in samples.items():
                last = runs_of[-1]
                fig[entry] = {
                    "ready_ms": spread([r["ready_ms"] for r in runs_of]),
                    "processes": last["processes"],
                    "resource_tracker": any(r["resource_tracker"] for r in runs_of),
                    "dev_shm_mappings": max(r["dev_shm_mappings"] for r in runs_of),
                    "rss_mib": {
                        k: round(statistics.median(r["rss_kib"][k] for r in runs_of) / 1024, 1)
                        for k in ("daemon", "executor", "total")
                    },
                    "pss_mib_total": round(
                        statistics.median(r["pss_kib_total"] for r in runs_of) / 1024, 1
                    ),
                    "executor_locked_mib": round(last["executor_locked_kib"] / 1024, 1),
                    "executor_fifo": last["executor_fifo"],
                }
            result["modes"][mode] = fig
    result["load_after"] = os.getloadavg()[0]
    return result


def report(result: dict[str, Any]) -> None:
    print(
        f"motorctld start-up, {result['runs']} runs each ({result['python']} "
        f"{result['python_version']}, {result['cpus']} CPUs, load "
        f"{result['load_before']:.2f} -> {result['load_after']:.2f}):"
    )
    for mode, fig in result["modes"].items():
        bare = fig["bare_interpreter_ms"]
        print(
            f"  bytecode {mode}: a bare interpreter {bare['median']} ms (min {bare['min']})"
            + (
                "; NOTE: the checkout has __pycache__, so this is not cold"
                if fig.get("checkout_has_bytecode")
                else ""
            )
        )
        for entry in ENTRIES:
            if entry not in fig:
                continue
            f = fig[entry]
            r, rss = f["ready_ms"], f["rss_mib"]
            print(
                f"    {entry:9s} READY median {r['median']:6.1f} ms (min {r['min']:.1f}, "
                f"max {r['max']:.1f}); {f['processes']} processes, resource tracker "
                f"{'YES' if f['resource_tracker'] else 'no'}, /dev/shm mappings "
                f"{f['dev_shm_mappings']}; RSS daemon {rss['daemon']} + executor "
                f"{rss['executor']} = {rss['total']} MiB (PSS {f['pss_mib_total']} MiB; "
                f"executor locks {f['executor_locked_mib']} MiB, SCHED_FIFO "
                f"{'yes' if f['executor_fifo'] else 'no'})"
            )
    print(
        f"  targets: READY <= {READY_TARGET_MS:.0f} ms, no resource tracker, RSS <= "
        f"{RSS_TARGET_MIB:.0f} MiB"
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
        help="motorctld (the command), main (python -m motorctl.daemon.main)",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args()
    modes = ["cached", "sources"] if args.bytecode == "both" else [args.bytecode]
    entries = list(ENTRIES) if args.entry == "both" else [args.entry]
    result = measure(args.runs, modes, entries)
    report(result)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
