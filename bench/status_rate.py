"""How fast `motorctld --status` can be read while 3 motors step: reads/s and per-read latency.

A real daemon (bench/steps.py's, without real-time priority or a pinned CPU) runs 3 motors
at --rate step/s each; this process reads its status socket with ``read_status`` paced at
--per-s reads a second (as bench/steps.py's ``status`` scenario does: a read, then sleep
until the next slot if there is time left) for --seconds, and reports the rate reached and
the per-read latency (connect to JSON parsed) p50/p99/max. ``--per-s 0`` reads back to
back: the ceiling.

Not a step-timing benchmark: bench/steps.py measures what the reads do to the steps (on a
quiet machine, with real-time priority).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.steps import config_text  # noqa: E402  (the daemon of its status scenario)
from motorctl.daemon.status.reader import read_status  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402


def quantile(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return 0.0
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` (its threads; not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def read_paced(sock: Path, seconds: float, per_s: int) -> tuple[int, float, list[float], int]:
    """(reads, elapsed s, per-read latencies in s, bytes of the last document)."""
    period = 1.0 / per_s if per_s else 0.0
    lat: list[float] = []
    size = 0
    t0 = time.monotonic()
    end = t0 + seconds
    nxt = t0
    while time.monotonic() < end:
        a = time.perf_counter()
        doc = read_status(sock)
        lat.append(time.perf_counter() - a)
        if not size:
            size = len(json.dumps(doc))
        if period:
            nxt += period
            d = nxt - time.monotonic()
            if d > 0:
                time.sleep(d)
    return len(lat), time.monotonic() - t0, lat, size


def measure(args: argparse.Namespace) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        d = DaemonProcess(work, config_text(prio=0, cpu=-1, kind=args.executor))
        d.start()
        try:
            with d.client() as c:
                for m in range(3):
                    c.move(m, True, speed=args.rate // 1000)
                time.sleep(0.5)  # past the ramps
                assert d.proc is not None
                before = d.status()["steps"]
                cpu0 = cpu_s(d.proc.pid)
                n, elapsed, lat, size = read_paced(
                    d.state_dir / "status.sock", args.seconds, args.per_s
                )
                cpu = cpu_s(d.proc.pid) - cpu0
                after = d.status()
                for m in range(3):
                    c.stop(m, hard=True)
        finally:
            d.close()
            shutil.rmtree(work / "state", ignore_errors=True)
    lat.sort()
    moving = [m["state"] for m in after["motors"]]
    return {
        "executor": args.executor,
        "target_reads_per_s": args.per_s,
        "reads": n,
        "reads_per_s": round(n / elapsed, 1),
        "read_p50_ms": round(quantile(lat, 0.5) * 1e3, 3),
        "read_p99_ms": round(quantile(lat, 0.99) * 1e3, 3),
        "read_max_ms": round(lat[-1] * 1e3, 3) if lat else 0.0,
        "status_bytes": size,
        "daemon_cpu_percent": round(100 * cpu / elapsed, 1),
        "steps_in_window": after["steps"]["steps"] - before["steps"],
        "motor_states_at_end": ",".join(moving),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0, help="length of the read window")
    ap.add_argument(
        "--per-s", type=int, default=1000, help="target reads a second (0: back to back)"
    )
    ap.add_argument("--rate", type=int, default=10000, help="step/s per motor")
    ap.add_argument("--executor", default="process", choices=("process", "thread"))
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON (flat keys)")
    args = ap.parse_args()
    fig = measure(args)
    print(
        f"status reads against a daemon ({fig['executor']} executor, 3 motors x "
        f"{args.rate} step/s, {fig['steps_in_window']} steps in the window):"
    )
    print(
        f"  {fig['reads_per_s']} reads/s (target {args.per_s or 'back to back'}), "
        f"per read p50 {fig['read_p50_ms']} ms, p99 {fig['read_p99_ms']} ms, "
        f"max {fig['read_max_ms']} ms; {fig['status_bytes']} bytes a document"
    )
    print(
        f"  the daemon's process used {fig['daemon_cpu_percent']} % of a CPU meanwhile "
        "(its threads; the process executor's own process not counted)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
