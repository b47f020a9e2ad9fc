"""Step-edge lateness of motorctld's step executor against cyclictest, in one run.

Lateness is measured inside the executor: the mock GPIO is written and the step core
records (edge time - planned time) in a 1 us histogram, read over the status socket at the
start and end of a steady-state window. Scenarios, all with the executor on the same CPU:

  cyclictest   cyclictest -m -p PRIO -i PERIOD -a CPU (rt-tests), the reference
  idle         3 motors running, no traffic on the PTY
  flood        the same while a client floods the daemon with commands over its PTY
  status       the same while a client reads the status socket 1,000 times a second
  sweep        aggregate step rates over 3 motors, on each step core (compiled, python), going
               up until a window fails: the highest whose p99 stays within 1.5x
               cyclictest's p99 (the motors' max_speed, 200,000 step/s, ends it otherwise)
  stall        one motor at 5,000 step/s, the executor stopped for 50 ms (SIGSTOP/SIGCONT
               of the executor process; of the whole daemon for the thread kind): the fault
               must be latched and no two steps closer than the profile's bound
  cost         CPU time per step of each step core (in this process, mock lines, a
               virtual clock: the Python core's step() per edge, the compiled core's
               whole loop per edge)

idle, flood, status and stall run the daemon's default step core (the compiled one where it
is built); idle runs again on the Python core. Targets: idle p99 <= 1.1x cyclictest p99 on
the compiled core; flood and status p99 <= 1.5x idle p99; the compiled core >= 300,000
steps/s within 1.5x cyclictest p99 and >= 3x the Python core's in the same run, <= 0.5 us
of CPU per step on mock lines. Needs root (SCHED_FIFO) and rt-tests
(apt-get install rt-tests). With --unlimited-rt it sets kernel.sched_rt_runtime_us=-1 for
the run and restores it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import rt_runtime, rt_throttling_off  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402

CONFIG = """
[units]
run_speed_factor = 1000.0      # SPEED byte n = n*1000 step/s, so the sweep can pick rates
[step_thread]
priority = {prio}
cpu = {cpu}
executor = "{kind}"
lock_memory = true             # as a user runs it (test daemons would not lock)
{extra}
[mock]
wires = []
lose_steps = {lose_steps}           # the real motors' rule only where the stall asks for it
[[motors]]
name = "a"
max_speed = 200000.0
max_accel = 10000000.0
default_accel = 2000000.0
default_decel = 2000000.0
  [motors.mock]
  endstop_min = -8388000
  endstop_max = 8388000
"""


def config_text(
    prio: int,
    cpu: int,
    kind: str = "process",
    lose_steps: bool = False,
    step_thread: str = "",
    core: str = "auto",
) -> str:
    """Three motors; ``step_thread``: more ``[step_thread]`` lines (``key = value``);
    ``lose_steps``: the executor judges lateness as for real motors (docs/timing.md);
    ``core``: the step core."""
    step_thread = f'core = "{core}"\n{step_thread}'
    one = CONFIG.split("[[motors]]")[1]
    head = CONFIG.split("[[motors]]")[0].format(
        prio=prio, cpu=cpu, kind=kind, lose_steps=str(lose_steps).lower(), extra=step_thread
    )
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
        [
            exe,
            "-m",
            "-q",
            "-p",
            str(prio),
            "-i",
            str(period_us),
            "-D",
            f"{seconds:.0f}",
            "-h",
            "20000",
            "-a",
            str(cpu),
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
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


def status_reader(state_dir: Path, seconds: float, per_s: int) -> subprocess.Popen[bytes]:
    code = (
        "import time\n"
        "from pathlib import Path\n"
        "from motorctl.daemon.status.reader import read_status\n"
        f"p=Path({str(state_dir / 'status.sock')!r}); end=time.monotonic()+{seconds}; n=0\n"
        f"period=1/{per_s}; nxt=time.monotonic()\n"
        "while time.monotonic()<end:\n"
        "    read_status(p); n+=1; nxt+=period\n"
        "    d=nxt-time.monotonic()\n"
        "    if d>0: time.sleep(d)\n"
        "print(n)\n"
    )
    return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE)


def memory_kb(pid: int | None) -> dict[str, int]:
    """VmRSS and VmLck (mlockall) of a process, in kB."""
    out = {"rss_kb": 0, "locked_kb": 0}
    if pid is None:
        return out
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmLck"):
            out["rss_kb" if key == "VmRSS" else "locked_kb"] = int(value.split()[0])
    return out


def run_daemon(
    work: Path,
    prio: int,
    rate_per_motor: int,
    seconds: float,
    cpu: int,
    flood_cpu: int | None,
    kind: str = "process",
    status_per_s: int = 0,
    core: str = "auto",
) -> dict[str, Any]:
    text = config_text(prio, cpu, kind, core=core)
    d = DaemonProcess(work, text, as_user=True)  # it pins its executor
    d.start()
    try:
        ran = d.status()["executor"]["core"]
        if core != "auto" and ran != core:
            raise SystemExit(f"asked for the {core} step core, the daemon runs {ran}")
        with d.client() as c:
            for m in range(3):
                c.move(m, True, speed=rate_per_motor // 1000)
            time.sleep(0.5)  # ramps done: the window starts in steady state
            before = hist_of(d.status(histogram=True))
            flooder = flood(str(d.pty), seconds, flood_cpu) if flood_cpu is not None else None
            if status_per_s:
                flooder = status_reader(d.state_dir, seconds, status_per_s)
            t0 = time.monotonic()
            if flooder is not None:
                out, _ = flooder.communicate(timeout=seconds + 30)
                commands = int(out.strip() or 0)
            else:
                time.sleep(seconds)
                commands = 0
            elapsed = time.monotonic() - t0
            status = d.status(histogram=True)
            after = hist_of(status)
            assert d.proc is not None
            memory = {f"daemon_{k}": v for k, v in memory_kb(d.proc.pid).items()}
            memory.update(
                {f"executor_{k}": v for k, v in memory_kb(status["executor"]["pid"]).items()}
            )
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
    if status_per_s:
        result["status_reads_per_s"] = round(commands / elapsed)
    result["timing_lost"] = status["steps"].get("timing_lost", 0)
    result["core"] = ran
    result.update(memory)
    return result


def stall(work: Path, prio: int, cpu: int, kind: str) -> dict[str, Any]:
    """50 ms without the executor while a motor runs at 5,000 step/s, judged as for a real
    motor (16 microsteps, 0.5 full steps of lag: 1.6 ms late at most)."""
    d = DaemonProcess(work, config_text(prio, cpu, kind, lose_steps=True), as_user=True)
    d.start()
    try:
        with d.client() as c:
            c.move(0, True, speed=5)  # 5 x 1000 step/s
            time.sleep(0.5)
            st = d.status()
            pid = st["executor"]["pid"] if kind == "process" else d.proc.pid  # type: ignore[union-attr]
            os.kill(pid, signal.SIGSTOP)
            time.sleep(0.05)
            os.kill(pid, signal.SIGCONT)
            time.sleep(0.5)
            st = d.status()
    finally:
        d.close()
        shutil.rmtree(work / "state", ignore_errors=True)
    fault = st["motors"][0]["fault"] or ""
    return {
        "fault": fault,
        "fault_latched": fault.startswith("step timing lost"),
        "position_lost": st["motors"][0]["position_lost"],
        "min_gap_us": st["steps"]["min_gap_ns"] / 1000,
        "profile_bound_us": round((1 / 100_000.0 - 5e-6) * 1e6, 1),
    }


def core_cost_us(core: str = "python", steps: int = 30_000) -> float:
    """CPU time per step of a step core on mock lines (3 motors), in this process, on a
    virtual clock: the Python core's ``step()`` per edge (the loop's other work not
    counted), the compiled core's whole loop per edge (``run_until``: refill, end stops,
    due times, the step; its rings and cells in a shared block)."""
    from motorctl.hal.backends.mock.backend import build, build_step_io
    from motorctl.hal.backends.mock.world import mock_axis
    from motorctl.hal.interfaces import VirtualClock
    from motorctl.hal.shm import SharedBlock
    from motorctl.hal.spec import HardwareSpec
    from motorctl.motion.executors.compiled_core import CompiledStepCore
    from motorctl.motion.executors.core_cells import COUNTER_NAMES, STEPS, CoreInbox
    from motorctl.motion.executors.process.rings import Layout, Shared
    from motorctl.motion.executors.segments import StepSegment
    from motorctl.motion.executors.step_core import StepCore
    from motorctl.motion.latency import LatencyStats
    from tests.support.motor_defaults import motor_limits

    clock = VirtualClock()
    far = mock_axis(endstop_min=-(10**9), endstop_max=10**9)
    spec = HardwareSpec(axes=(far,) * 3, options={"timeline_len": 1000})
    hw = build(spec, clock)
    io = build_step_io(spec, clock, hw)
    limits = [motor_limits(1e-6)] * 3
    start = round(clock.now() * 1e9) + 1000
    if core == "compiled":
        layout = Layout(3, len(io.inputs.names))
        shm = SharedBlock.create(layout.size, "motorctl-bench")
        shared = Shared(shm, layout)
        compiled = CompiledStepCore(io, limits, shared)
        for m in range(3):
            assert shared.segs[m].put(start, 10_000 + 7 * m, steps // 3, 0, 1, 0, 0)
        compiled.refill()
        t = time.process_time()
        compiled.run_until(start + (steps // 3) * 10_100)
        cost = (time.process_time() - t) / steps * 1e6
        made = int(shared.counters[STEPS])
        compiled.close()
        shared.release()
        shm.close()
        if made != steps // 3 * 3:
            raise SystemExit(f"the compiled core made {made} of {steps} steps")
        return round(cost, 3)
    inbox = CoreInbox(3)
    python = StepCore(
        io,
        limits,
        inbox,
        lambda e: None,
        positions=[0] * 3,
        levels=[0] * 6,
        counters=[0] * len(COUNTER_NAMES),
        stats=LatencyStats(),
    )
    for m in range(3):
        inbox.queues[m].append(StepSegment(start, 10_000 + 7 * m, steps // 3, 0, 1, 0))
    python.refill()
    t = time.process_time()
    while (d := python.deadline()) is not None:
        clock.advance_to(d / 1e9)
        python.step(d)
    return round((time.process_time() - t) / steps * 1e6, 3)


def sweep(
    args: argparse.Namespace, work: Path, core: str, ct_p99: float
) -> tuple[list[dict[str, Any]], int]:
    """Per-motor rates from ``--sweep`` in order on ``core`` until a window's p99 goes beyond
    1.5x cyclictest's: the windows, and the highest aggregate rate within it."""
    out: list[dict[str, Any]] = []
    best = 0
    for per_motor in (int(x) for x in args.sweep.split(",")):
        r = run_daemon(
            work, args.prio, per_motor, args.seconds, args.cpu, None, args.executor, core=core
        )
        r["per_motor"] = per_motor
        r["within_1_5x_cyclictest"] = r.get("p99_us", 1e9) <= 1.5 * max(ct_p99, 1.0)
        out.append(r)
        if not r["within_1_5x_cyclictest"]:
            break
        best = max(best, r["rate_steps_per_s"])
    return out, best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0, help="length of each window")
    ap.add_argument("--prio", type=int, default=50)
    ap.add_argument("--cpu", type=int, default=0, help="the executor's CPU")
    ap.add_argument("--period-us", type=int, default=100, help="cyclictest interval")
    ap.add_argument("--rate", type=int, default=10000, help="step/s per motor, idle/flood/status")
    ap.add_argument(
        "--sweep",
        default="10000,20000,30000,40000,50000,60000,80000,100000,120000,150000,200000",
        help="step/s per motor to try, in order, on each core until a window fails (x3 "
        "aggregate; the motors' max_speed is 200000)",
    )
    ap.add_argument(
        "--cores",
        default="compiled,python",
        help="the step cores to sweep and to measure the cost of",
    )
    ap.add_argument("--executor", default="process", choices=("process", "thread"))
    ap.add_argument(
        "--unlimited-rt",
        action="store_true",
        help="set kernel.sched_rt_runtime_us=-1 for the run (restored after)",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON (flat keys)")
    args = ap.parse_args()
    if os.geteuid() != 0:
        print("note: not root: SCHED_FIFO will be refused, figures are best effort")
    with rt_throttling_off(args.unlimited_rt) as old_rt:
        figures = measure(args)
    figures["sched_rt_runtime_us_before"] = old_rt or "?"
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


def measure(args: argparse.Namespace) -> dict[str, Any]:
    rt = rt_runtime() or "?"
    kind = args.executor
    cores = [c for c in args.cores.split(",") if c]
    fig: dict[str, Any] = {
        "executor": kind,
        "sched_rt_runtime_us": rt,
        "cpu": args.cpu,
        "priority": args.prio,
        "seconds": args.seconds,
        "load_average_1m": os.getloadavg()[0],
    }
    flood_cpu = (args.cpu + 1) % (os.cpu_count() or 1)
    sweeps: dict[str, list[dict[str, Any]]] = {}
    best: dict[str, int] = {}
    idle_of: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        ct = cyclictest(args.prio, args.period_us, args.seconds, args.cpu)
        idle = run_daemon(work, args.prio, args.rate, args.seconds, args.cpu, None, kind)
        idle_of[idle["core"]] = idle
        fl = run_daemon(work, args.prio, args.rate, args.seconds, args.cpu, flood_cpu, kind)
        stq = run_daemon(
            work, args.prio, args.rate, args.seconds, args.cpu, None, kind, status_per_s=1000
        )
        for core in cores:
            if core not in idle_of:
                idle_of[core] = run_daemon(
                    work, args.prio, args.rate, args.seconds, args.cpu, None, kind, core=core
                )
            sweeps[core], best[core] = sweep(args, work, core, ct["p99_us"])
        stl = stall(work, args.prio, args.cpu, kind)
        fig["load_average_1m_end"] = os.getloadavg()[0]
    costs = {core: core_cost_us(core, 300_000 if core == "compiled" else 30_000) for core in cores}
    for name, r in (("cyclictest", ct), ("idle", idle), ("flood", fl), ("status", stq)):
        for k in ("p50_us", "p99_us", "p999_us", "max_us", "rate_steps_per_s"):
            if k in r:
                fig[f"{name}_{k}"] = r[k]
    fig["default_core"] = idle["core"]
    fig["flood_commands_per_s"] = fl.get("flood_commands_per_s", 0)
    fig["status_reads_per_s"] = stq.get("status_reads_per_s", 0)
    for core in cores:
        for r in sweeps[core]:
            fig[f"sweep_{core}_{3 * r['per_motor']}_p99_us"] = r.get("p99_us", 0)
            fig[f"sweep_{core}_{3 * r['per_motor']}_rate_steps_per_s"] = r["rate_steps_per_s"]
        fig[f"best_rate_{core}"] = best[core]
        fig[f"sweep_{core}_ended"] = (
            "failed" if not sweeps[core][-1]["within_1_5x_cyclictest"] else "max_speed"
        )
        fig[f"core_cost_us_{core}"] = costs[core]
        fig[f"idle_vs_cyclictest_p99_{core}"] = round(
            idle_of[core].get("p99_us", 0) / max(ct["p99_us"], 1.0), 2
        )
    if "compiled" in best and "python" in best:
        fig["best_rate_compiled_vs_python"] = round(best["compiled"] / max(best["python"], 1), 2)
    fig["best_rate_within_1_5x"] = best.get(idle["core"], 0)
    fig["idle_vs_cyclictest_p99"] = round(idle["p99_us"] / max(ct["p99_us"], 1.0), 2)
    fig["flood_vs_idle_p99"] = round(fl["p99_us"] / max(idle["p99_us"], 1.0), 2)
    fig["status_vs_idle_p99"] = round(stq["p99_us"] / max(idle["p99_us"], 1.0), 2)
    fig["stall_fault_latched"] = stl["fault_latched"]
    fig["stall_position_lost"] = stl["position_lost"]
    fig["stall_min_gap_us"] = stl["min_gap_us"]
    fig["stall_profile_bound_us"] = stl["profile_bound_us"]
    fig["executor_step_cost_us"] = costs.get(idle["core"], 0.0)
    for k in ("daemon_rss_kb", "daemon_locked_kb", "executor_rss_kb", "executor_locked_kb"):
        fig[k] = idle.get(k, 0)  # while 3 motors step
    fig["timing_lost_in_windows"] = sum(r.get("timing_lost", 0) for r in (idle, fl, stq))

    def row(name: str, r: dict[str, Any]) -> str:
        return (
            f"  {name:<28} p50 {r.get('p50_us', 0):7.0f}  p99 {r.get('p99_us', 0):7.0f}  "
            f"p99.9 {r.get('p999_us', 0):7.0f}  max {r.get('max_us', 0):7.0f} us"
            + (f"  ({r['rate_steps_per_s']} steps/s)" if "rate_steps_per_s" in r else "")
        )

    print(
        f"step-edge lateness, {kind} executor on CPU {args.cpu}, SCHED_FIFO {args.prio}, "
        f"sched_rt_runtime_us {rt}, load average {fig['load_average_1m']:.1f} at the start, "
        f"{fig['load_average_1m_end']:.1f} at the end; default step core {idle['core']}:"
    )
    print(row(f"cyclictest -i {args.period_us}", ct))
    print(row(f"idle 3x{args.rate} ({idle['core']})", idle))
    print(row("under a command flood", fl) + f"  [{fig['flood_commands_per_s']} commands/s]")
    print(row("under status reads", stq) + f"  [{fig['status_reads_per_s']} reads/s]")
    for core in cores:
        if idle_of[core] is not idle:
            print(row(f"idle 3x{args.rate} ({core})", idle_of[core]))
        for r in sweeps[core]:
            print(
                row(f"sweep {core} 3x{r['per_motor']}", r)
                + ("" if r["within_1_5x_cyclictest"] else "  > 1.5x cyclictest")
            )
    for core in cores:
        target = " (target <= 1.1)" if core == "compiled" else ""
        print(
            f"idle p99 / cyclictest p99, {core} core = "
            f"{fig[f'idle_vs_cyclictest_p99_{core}']}{target}"
        )
    print(f"flood p99 / idle p99 = {fig['flood_vs_idle_p99']} (target <= 1.5)")
    print(f"status p99 / idle p99 = {fig['status_vs_idle_p99']} (target <= 1.5)")
    for core in cores:
        target = " (target >= 300000 and >= 3x python's)" if core == "compiled" else ""
        ended = "a window failed" if fig[f"sweep_{core}_ended"] == "failed" else "max_speed"
        print(
            f"highest aggregate rate with p99 <= 1.5x cyclictest, {core} core: "
            f"{best[core]} steps/s{target} (the sweep ended at {ended})"
        )
    if "best_rate_compiled_vs_python" in fig:
        print(f"compiled / python best rate = {fig['best_rate_compiled_vs_python']}")
    print(
        f"50 ms stall at 5000 step/s: fault latched {stl['fault_latched']} ({stl['fault']!r}),"
        f" smallest gap {stl['min_gap_us']:.1f} us (bound {stl['profile_bound_us']} us)"
    )
    for core in cores:
        target = " (target <= 0.5)" if core == "compiled" else ""
        print(f"step core CPU per step, {core}: {costs[core]} us{target}")
    print(
        f"memory while 3 motors step: daemon RSS {fig['daemon_rss_kb'] / 1024:.1f} MB "
        f"(locked {fig['daemon_locked_kb'] / 1024:.1f}), step executor RSS "
        f"{fig['executor_rss_kb'] / 1024:.1f} MB (locked {fig['executor_locked_kb'] / 1024:.1f})"
    )
    return fig


if __name__ == "__main__":
    raise SystemExit(main())
