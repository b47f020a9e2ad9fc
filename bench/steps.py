"""Step-edge lateness of motorctld's step thread against cyclictest, in one run.

Lateness is measured inside the daemon: the mock GPIO timestamps each step write and the
step thread records (edge time - planned time) in a 1 us histogram, read over the status
socket at the start and end of a steady-state window. Scenarios, all on the same CPU:

  cyclictest   cyclictest -m -p PRIO -i PERIOD -a CPU (rt-tests), the reference
  idle         3 motors running, no traffic on the PTY
  flood        the same while a client floods the daemon with commands over its PTY
  sweep        aggregate step rates over 3 motors: the highest whose p99 stays within
               1.5x cyclictest's p99

Targets: idle p99 <= 1.2x cyclictest p99; flood p99 <= 1.5x idle p99; >= 50,000 steps/s.
Needs root (SCHED_FIFO) and rt-tests (apt-get install rt-tests).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.daemon_proc import DaemonProcess  # noqa: E402

RT_RUNTIME = Path("/proc/sys/kernel/sched_rt_runtime_us")

CONFIG = """
[units]
run_speed_factor = 1000.0      # SPEED byte n = n*1000 step/s, so the sweep can pick rates
[step_thread]
priority = {prio}
cpu = {cpu}
[[motors]]
name = "a"
max_speed = 100000.0
max_accel = 1000000.0
default_accel = 500000.0
default_decel = 500000.0
  [motors.mock]
  endstop_min = -8388000
  endstop_max = 8388000
"""


def config_text(prio: int, cpu: int) -> str:
    one = CONFIG.split("[[motors]]")[1]
    head = CONFIG.split("[[motors]]")[0].format(prio=prio, cpu=cpu)
    return head + "".join("[[motors]]" + one.replace('"a"', f'"{n}"') for n in "abc")


def percentiles(hist: dict[int, int]) -> dict[str, float]:
    total = sum(hist.values())
    out: dict[str, float] = {"count": total}
    if total == 0:
        return out
    keys = sorted(hist)
    for name, q in (("p50_us", 0.5), ("p99_us", 0.99), ("p999_us", 0.999)):
        seen = 0
        for k in keys:
            seen += hist[k]
            if seen >= q * total:
                out[name] = float(k)
                break
    out["max_us"] = float(keys[-1])
    return out


def cyclictest(prio: int, period_us: int, seconds: float, cpu: int) -> dict[str, float]:
    exe = shutil.which("cyclictest")
    if exe is None:
        raise SystemExit("cyclictest not found: apt-get install rt-tests")
    out = subprocess.run(
        [exe, "-m", "-q", "-p", str(prio), "-i", str(period_us), "-D", f"{seconds:.0f}",
         "-h", "20000", "-a", str(cpu)], capture_output=True, text=True, check=True).stdout
    hist = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit() and int(parts[1]):
            hist[int(parts[0])] = int(parts[1])
    max_line = [ln for ln in out.splitlines() if ln.startswith("# Max Latencies")]
    result = percentiles(hist)
    if max_line:
        result["max_us"] = float(max_line[0].split()[-1])
    return result


def hist_of(status: dict[str, Any]) -> dict[int, int]:
    return {int(k): v for k, v in status["steps"]["histogram_us"].items()}


def flood(port: str, seconds: float, cpu: int) -> subprocess.Popen[bytes]:
    code = (
        "import os,sys,time,serial\n"
        f"os.sched_setaffinity(0, {{{cpu}}})\n"
        "from motorctl.protocol.codec import CodecOptions, IsReady, GetAbsPos, encode_command\n"
        "o=CodecOptions(); f=[encode_command(IsReady(0),o), encode_command(GetAbsPos(1),o)]\n"
        f"s=serial.Serial({port!r},115200,timeout=2); end=time.monotonic()+{seconds}; n=0\n"
        "while time.monotonic()<end:\n"
        "    s.write(f[n%2]); assert len(s.read(5))==5; n+=1\n"
        "print(n)\n"
    )
    return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE)


def run_daemon(work: Path, prio: int, rate_per_motor: int, seconds: float, cpu: int,
               flood_cpu: int | None) -> dict[str, Any]:
    d = DaemonProcess(work, config_text(prio, cpu))  # the daemon pins its step thread
    d.start()
    try:
        with d.client() as c:
            for m in range(3):
                c.move(m, True, speed=rate_per_motor // 1000)
            time.sleep(0.5)  # ramps done: the window starts in steady state
            before = hist_of(d.status())
            flooder = flood(str(d.pty), seconds, flood_cpu) if flood_cpu is not None else None
            t0 = time.monotonic()
            if flooder is not None:
                out, _ = flooder.communicate(timeout=seconds + 30)
                commands = int(out.strip() or 0)
            else:
                time.sleep(seconds)
                commands = 0
            elapsed = time.monotonic() - t0
            status = d.status()
            after = hist_of(status)
            for m in range(3):
                c.stop(m, hard=True)
    finally:
        d.close()
        shutil.rmtree(work / "state", ignore_errors=True)
    window = {k: after.get(k, 0) - before.get(k, 0) for k in after}
    result: dict[str, Any] = percentiles({k: v for k, v in window.items() if v})
    result["rate_steps_per_s"] = round(result["count"] / elapsed)
    result["late_steps_total"] = status["steps"]["late"]
    if flood_cpu is not None:
        result["flood_commands_per_s"] = round(commands / elapsed)
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0, help="length of each window")
    ap.add_argument("--prio", type=int, default=50)
    ap.add_argument("--cpu", type=int, default=0)
    ap.add_argument("--period-us", type=int, default=100, help="cyclictest interval")
    ap.add_argument("--rate", type=int, default=10000, help="step/s per motor, idle and flood")
    ap.add_argument("--sweep", default="5000,10000,15000,20000,25000",
                    help="step/s per motor to try (x3 aggregate)")
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args()
    if os.geteuid() != 0:
        print("note: not root: SCHED_FIFO will be refused, figures are best effort")
    rt = RT_RUNTIME.read_text().strip() if RT_RUNTIME.exists() else "?"
    figures: dict[str, Any] = {"sched_rt_runtime_us": rt, "cpu": args.cpu,
                               "priority": args.prio}
    flood_cpu = (args.cpu + 1) % (os.cpu_count() or 1)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        figures["cyclictest"] = ct = cyclictest(args.prio, args.period_us, args.seconds, args.cpu)
        figures["idle"] = idle = run_daemon(work, args.prio, args.rate, args.seconds, args.cpu,
                                            None)
        figures["flood"] = fl = run_daemon(work, args.prio, args.rate, args.seconds, args.cpu,
                                           flood_cpu)
        sweep = []
        best = 0
        for per_motor in (int(x) for x in args.sweep.split(",")):
            r = run_daemon(work, args.prio, per_motor, args.seconds, args.cpu, None)
            r["per_motor"] = per_motor
            r["within_1_5x_cyclictest"] = r.get("p99_us", 1e9) <= 1.5 * max(ct["p99_us"], 1.0)
            sweep.append(r)
            if r["within_1_5x_cyclictest"]:
                best = max(best, r["rate_steps_per_s"])
        figures["sweep"] = sweep
        figures["best_rate_within_1_5x"] = best
    figures["idle_vs_cyclictest_p99"] = round(idle["p99_us"] / max(ct["p99_us"], 1.0), 2)
    figures["flood_vs_idle_p99"] = round(fl["p99_us"] / max(idle["p99_us"], 1.0), 2)

    def row(name: str, r: dict[str, Any]) -> str:
        return (f"  {name:<22} p50 {r.get('p50_us', 0):7.0f}  p99 {r.get('p99_us', 0):7.0f}  "
                f"p99.9 {r.get('p999_us', 0):7.0f}  max {r.get('max_us', 0):7.0f} us"
                + (f"  ({r['rate_steps_per_s']} steps/s)" if "rate_steps_per_s" in r else ""))

    print(f"step-edge lateness, CPU {args.cpu}, SCHED_FIFO {args.prio}, "
          f"sched_rt_runtime_us {rt}:")
    print(row(f"cyclictest -i {args.period_us}", ct))
    print(row(f"motorctld idle 3x{args.rate}", idle))
    print(row("motorctld under flood", fl)
          + f"  [{fl.get('flood_commands_per_s', 0)} commands/s]")
    for r in sweep:
        print(row(f"sweep 3x{r['per_motor']}", r)
              + ("" if r["within_1_5x_cyclictest"] else "  > 1.5x cyclictest"))
    print(f"idle p99 / cyclictest p99 = {figures['idle_vs_cyclictest_p99']} (target <= 1.2)")
    print(f"flood p99 / idle p99 = {figures['flood_vs_idle_p99']} (target <= 1.5)")
    print(f"highest aggregate rate with p99 <= 1.5x cyclictest: {best} steps/s "
          "(target >= 50000)")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
