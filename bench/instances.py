"""Two motorctld instances stepping at once, as two motorctld@ units run them: does either's
step executor starve the other's?

Each scenario starts two daemons, A and B (A only for 'alone'), on the embedded default (the
mock world: three motors between end stops 20,000 steps apart) with a state directory and a
PTY of their own, as motorctld@A and motorctld@B would run, and with their executors' CPUs
and priorities set per scenario in their configs:

  alone    A alone, its executor on one CPU: the reference (what the machine itself does)
  apart    A's executor on one CPU, B's on another, both SCHED_FIFO 50: the set-up
           docs/service.md prescribes ("Several instances")
  same     both executors on one CPU, both SCHED_FIFO 50: what happens when two instances
           are left to share a CPU (the counter-example)

Every motor of both daemons then runs MoveTo back and forth between -9000 and 9000 at --speed
step/s for --seconds (a motor that answers E4, 'step timing lost' with its position lost, is
left out from then on and counted). At the end each daemon's `motorctld --status
--histogram` gives its step lateness over the window (p50/p99/p99.9/max, late steps, steps
not made: 'timing lost'), and /proc its executor's CPUs and involuntary context switches.
Needs root for SCHED_FIFO (without it figures are best effort and say so). The mock's
simulated motors slide late steps and never fault for them (docs/timing.md, "Late steps:
slide, or stop"), so the histograms show how late steps came; --lose-steps judges them as
real motors (16 microsteps, 0.5 full steps of lag): a motor beyond it stops with E4.

The executor busy-waits the last spin_us (200 us) before each step, so above about
1,600 step/s per motor (3 motors) it never sleeps: two such executors keep two CPUs
busy with real-time work, the kernel's RT throttling (kernel.sched_rt_runtime_us, 95 %)
then parks each for 50 ms a second, whatever the layout, and with it set to -1 nothing
else runs on a 2-core machine. So the default speed, 500 step/s, leaves both CPUs time for
the daemons; --unlimited-rt sets -1 for the run and restores it (only where other CPUs
are left for the rest of the machine).

  python bench/instances.py [--seconds 10] [--speed 500] [--scenarios alone,apart,same] [--json F]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import rt_runtime, rt_throttling_off  # noqa: E402
from bench.steps import percentiles  # noqa: E402
from motorctl.client.client import Client, DeviceError  # noqa: E402
from motorctl.daemon.config import default_config_text  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402

SPEED_FACTOR = 100.0  # MoveTo's SPEED byte n = n * 100 step/s here (the default is 4)
ENDS = (-9000, 9000)  # inside the mock's end stops at -10,000 and 10,000


def config(cpu: int, priority: int, lose_steps: bool) -> str:
    """The embedded default with the executor's CPU, priority and lateness rule set and a
    coarser SPEED."""
    text = default_config_text()
    for key, value in (
        ("cpu", cpu),
        ("priority", priority),
        ("lose_steps", str(lose_steps).lower()),
        ("move_speed_factor", SPEED_FACTOR),
    ):
        lines = [ln for ln in text.splitlines() if ln.split("=")[0].strip() == key]
        assert len(lines) == 1, f"{key}: {lines}"
        text = text.replace(lines[0], f"{key} = {value}")
    return text


def status(state_dir: Path) -> dict[str, Any]:
    """What `motorctld --status --histogram` prints, as a user would read it."""
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--status",
            "--histogram",
            "--state-dir",
            str(state_dir),
        ],
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
        cwd=ROOT,
    )
    doc: dict[str, Any] = json.loads(out.stdout)
    return doc


def proc_status(pid: int) -> dict[str, str]:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        fields[key] = value.strip()
    return fields


class Instance:
    def __init__(self, name: str, work: Path, cpu: int, priority: int, lose_steps: bool) -> None:
        self.name = name
        work.mkdir(parents=True)
        self.daemon = DaemonProcess(work, config(cpu, priority, lose_steps), as_user=True)
        self.client: Client | None = None
        self.target = [ENDS[1]] * 3
        self.moves = 0
        self.lost: set[int] = set()

    def start(self) -> None:
        self.daemon.start()
        self.client = self.daemon.client()

    def step(self, speed_byte: int) -> None:
        """Send each motor at rest to its other end."""
        assert self.client is not None
        for m in range(3):
            if m in self.lost:
                continue
            try:
                if self.client.is_ready(m):
                    self.target[m] = ENDS[0] if self.target[m] == ENDS[1] else ENDS[1]
                    self.client.move_to(m, self.target[m], speed=speed_byte)
                    self.moves += 1
            except DeviceError:  # E4: 'step timing lost', position lost: the motor is out
                self.lost.add(m)

    def close(self) -> None:
        if self.client is not None:
            for m in range(3):
                with contextlib.suppress(Exception):  # it may have stopped already
                    self.client.stop(m, hard=True)
            self.client.close()
        self.daemon.close()


def scenario(
    work: Path, cpus: tuple[int, ...], priority: int, seconds: float, speed: int, lose_steps: bool
) -> dict[str, Any]:
    speed_byte = max(1, min(255, round(speed / SPEED_FACTOR)))
    insts = [
        Instance(n, work / n, cpu, priority, lose_steps) for n, cpu in zip("AB", cpus, strict=False)
    ]
    try:
        for inst in insts:
            inst.start()
        for inst in insts:
            inst.step(speed_byte)
        time.sleep(0.5)  # past the first ramps
        before = {i.name: status(i.daemon.state_dir) for i in insts}
        ctx0 = {i.name: proc_status(before[i.name]["executor"]["pid"]) for i in insts}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for inst in insts:
                inst.step(speed_byte)
            time.sleep(0.05)
        after = {i.name: status(i.daemon.state_dir) for i in insts}
        result: dict[str, Any] = {}
        for inst in insts:
            b, a = before[inst.name]["steps"], after[inst.name]["steps"]
            hb = {int(k): v for k, v in b["histogram_us"].items()}
            ha = {int(k): v for k, v in a["histogram_us"].items()}
            window = {k: v - hb.get(k, 0) for k, v in ha.items() if v - hb.get(k, 0) > 0}
            pid = after[inst.name]["executor"]["pid"]
            ctx1 = proc_status(pid)
            r: dict[str, Any] = percentiles(window)
            r["steps_per_s"] = round(r["count"] / seconds)
            r["late"] = a["late"] - b["late"]
            r["timing_lost"] = a.get("timing_lost", 0) - b.get("timing_lost", 0)
            r["motors_lost"] = len(inst.lost)
            r["moves"] = inst.moves
            r["executor_cpus"] = ctx1["Cpus_allowed_list"]
            r["executor_involuntary_switches"] = int(ctx1["nonvoluntary_ctxt_switches"]) - int(
                ctx0[inst.name]["nonvoluntary_ctxt_switches"]
            )
            result[inst.name] = r
        return result
    finally:
        for inst in insts:
            inst.close()


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each window")
    ap.add_argument("--speed", type=int, default=500, help="step/s of every motor")
    ap.add_argument("--priority", type=int, default=50, help="both executors' SCHED_FIFO")
    n = os.cpu_count() or 1
    ap.add_argument(
        "--cpus",
        default=f"{max(0, n - 2)},{n - 1}",
        help="the two executors' CPUs for 'apart' (default: the last two)",
    )
    ap.add_argument("--scenarios", default="alone,apart,same")
    ap.add_argument(
        "--lose-steps",
        action="store_true",
        help="judge late steps as for real motors ([mock] lose_steps = true): a "
        "lag beyond 0.5 full steps stops the motor with E4",
    )
    ap.add_argument(
        "--unlimited-rt",
        action="store_true",
        help="set kernel.sched_rt_runtime_us=-1 for the run (restored after)",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args()
    a, b = (int(c) for c in args.cpus.split(","))
    layouts: dict[str, tuple[int, ...]] = {"alone": (b,), "apart": (a, b), "same": (b, b)}
    if os.geteuid() != 0:
        print("note: not root: SCHED_FIFO will be refused, figures are best effort")
    old_rt = rt_runtime() or "?"
    figures: dict[str, Any] = {
        "speed": args.speed,
        "seconds": args.seconds,
        "priority": args.priority,
        "lose_steps": args.lose_steps,
        "cpus": n,
        "sched_rt_runtime_us": "-1" if args.unlimited_rt else old_rt,
        "load_average_1m": round(os.getloadavg()[0], 2),
    }
    with rt_throttling_off(args.unlimited_rt), tempfile.TemporaryDirectory() as tmp:
        for name in args.scenarios.split(","):
            figures[name] = scenario(
                Path(tmp) / name,
                layouts[name],
                args.priority,
                args.seconds,
                args.speed,
                args.lose_steps,
            )
    print(
        f"two instances, 3 motors each at {args.speed} step/s, {args.seconds:.0f} s windows, "
        f"SCHED_FIFO {args.priority}, {n} CPUs, sched_rt_runtime_us "
        f"{figures['sched_rt_runtime_us']}, load average {figures['load_average_1m']}:"
    )
    print(
        f"{'':8} {'':2} {'cpus':>5} {'steps/s':>8} {'p50':>6} {'p99':>6} {'p99.9':>7} "
        f"{'max':>7} {'late':>6} {'lost':>5} {'out':>4} {'preempted':>9}"
    )
    for name in args.scenarios.split(","):
        for inst, r in figures[name].items():
            print(
                f"{name:8} {inst:2} {r['executor_cpus']:>5} {r['steps_per_s']:>8} "
                f"{r.get('p50_us', 0):>6.0f} {r.get('p99_us', 0):>6.0f} "
                f"{r.get('p999_us', 0):>7.0f} {r.get('max_us', 0):>7.0f} {r['late']:>6} "
                f"{r['timing_lost']:>5} {r['motors_lost']:>4} "
                f"{r['executor_involuntary_switches']:>9}"
            )
    print(
        "(lateness in us from each daemon's `motorctld --status --histogram` over the window; "
        "late: steps later than late_threshold_us; lost: motors stopped by 'step timing "
        "lost'; out: motors that answered E4 since and were left out (position lost); "
        "preempted: the executor's involuntary context switches)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
