"""Lateness judged as the motor would feel it, on a quiet and on a noisy machine.

Each run is a fresh start of motorctld as a user starts it (`make run`: `--pty`, no config,
real-time priority and locked memory when root), then:

  walkthrough  the README's client walkthrough, line by line, as tests/docs/test_readme.py runs it
  sweep        every command of the protocol on every motor, pin and the DC motor, with the
               answers a host expects (a conformance-style sweep, ~80 transactions)
  fast         a second fresh start, the same world with its travel and ramps opened up (the
               embedded default's end stops are 20,000 steps apart and its ramps 8,000
               step/s^2: 25,000 step/s cannot be reached there): 3 motors at 25,000 step/s for
               10 s, then a soft StopMove each (how soon the deceleration took over)

Rules: `mock` is the embedded default as it is (the simulated motors never slip: a late
step slides its motor's move); `real` is the same world with `[mock] lose_steps = true`
and 16 microsteps, 0.5 full steps of tolerance: the rule a real motor gets.

Loads: `quiet`, and `loaded`: two CPU hogs (`yes > /dev/null`, normal priority) and a disk
writer (`dd ... conv=fsync` in a loop). cyclictest (`-m -p 50 -i 1000 -t 2`) runs under
each (load, rule) condition's load for 30 s before its runs (beside them it would compete
with a busy-waiting executor at the same priority): its maximum is reported with it.

Reported per condition: runs passed (mock rule: every check passed and not one E4; target
20 of 20), E4 answers, faults by cause, late steps absorbed, the worst lateness and worst lag
(full steps), soft stop take-over (ms, steps); for the real rule each fault with its speed and
lag, and whether every one is a lag beyond the tolerance. Needs root for SCHED_FIFO; sets
kernel.sched_rt_runtime_us=-1 for the run and restores it (3 motors at 25,000 step/s keep
the executor busy-waiting; docs/timing.md). `--json FILE` writes the figures.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench import rt_throttling_off  # noqa: E402
from motorctl.client.client import Client, DeviceError, error_text  # noqa: E402
from motorctl.daemon.config import default_config_text  # noqa: E402
from motorctl.daemon.status.reader import read_status  # noqa: E402
from motorctl.protocol.codec import ErrorCode  # noqa: E402
from tests.docs.test_readme import walkthrough  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402

#: "step N us late at R step/s: lag L full steps > max_lag_full_steps M"
LAG_FAULT = re.compile(
    r"step (\d+) us late at (\d+) step/s: lag ([\d.]+) full steps > "
    r"max_lag_full_steps ([\d.]+)"
)
FAST_SPEED = 7  # Move SPEED byte: 7 x 4096 step/s, clamped to max_speed (25,000)


def rule_config(rule: str, fast: bool) -> str | None:
    """The config text of a run: None for the embedded default itself."""
    if rule == "mock" and not fast:
        return None
    text = default_config_text()
    if rule == "real":
        assert "lose_steps = false" in text
        text = text.replace("lose_steps = false", "lose_steps = true")
    if fast:
        text = text.replace("endstop_min = -10000", "endstop_min = -8388000")
        text = text.replace("endstop_max = 10000", "endstop_max = 8388000")
        text = text.replace("default_accel = 8000.0", "default_accel = 200000.0")
        text = text.replace("default_decel = 8000.0", "default_decel = 200000.0")
        assert text.count("endstop_min = -8388000") == 3 and text.count("200000.0") >= 6
    return text


class Daemon(DaemonProcess):
    """motorctld started as a user starts it (`make run`), in its own folder."""

    def __init__(self, work: Path, config: str | None) -> None:
        super().__init__(work, config, state_dir=work / ".run" / "state", as_user=True)
        self.work = work
        self.start()

    def status(self, histogram: bool = False) -> dict[str, Any]:
        return read_status(self.state_dir / "status.sock", timeout=10.0, histogram=histogram)

    def stop(self) -> int | None:
        """SIGTERM; its exit status (None: it had to be killed)."""
        try:
            return self.terminate(30.0)
        except subprocess.TimeoutExpired:
            self.kill()
            return None
        finally:
            self.close()


# -- the three parts of a run ----------------------------------------------------------------
def run_walkthrough(d: Daemon) -> list[str]:
    """The README's walkthrough as written (each line in bash in the daemon's folder); the
    problems found, each naming its line."""
    venv = d.work / ".venv"
    if not venv.exists():
        venv.symlink_to(Path(sys.prefix), target_is_directory=True)
    problems: list[str] = []
    exports: list[str] = []
    for command, comment in walkthrough():
        if command.startswith("export "):
            exports.append(command)
            continue
        run = subprocess.run(
            ["bash", "-c", "; ".join(["set -u", *exports, command])],
            cwd=d.work,
            capture_output=True,
            text=True,
            timeout=60,
        )
        wanted = re.search(r"exit status (\d+)", comment)
        output = (run.stdout + run.stderr).strip()
        if run.returncode != (int(wanted.group(1)) if wanted else 0):
            problems.append(f"{command!r}: exit {run.returncode}: {output[-200:]}")
        elif not command.startswith(".venv/bin/motorctld --status"):
            last = output.splitlines()[-1] if output else ""
            if last != "ok" and not comment.startswith(last):
                problems.append(f"{command!r}: printed {last!r}")
    return problems


def expect(
    problems: list[str],
    what: str,
    call: Callable[..., object],
    *args: Any,
    want: object = None,
    error: int | None = None,
) -> object:
    """Run one transaction, ``call(*args)``; note a problem when its answer is not the one
    expected (``want``, or the error code ``error``)."""
    try:
        got = call(*args)
    except DeviceError as exc:
        if error is None or exc.code != error:
            problems.append(
                f"{what}: {exc}; expected "
                + ("an answer" if error is None else error_text(ErrorCode(error)))
            )
        return None
    if error is not None:
        problems.append(f"{what}: answered {got!r}; expected {error_text(ErrorCode(error))}")
    elif want is not None and got != want:
        problems.append(f"{what}: {got!r}; expected {want!r}")
    return got


def run_sweep(d: Daemon) -> list[str]:
    """Every command, as a host uses it, on the embedded default's world (after the
    walkthrough: motor 0 homed at its lower end stop, so every target is above it)."""
    p: list[str] = []
    with Client(str(d.pty), timeout=10.0) as c:
        for m in range(3):
            target = 300 + 100 * m
            expect(p, f"IsReady({m})", c.is_ready, m, want=True)
            expect(p, f"MoveTo({m})", c.move_to, m, target, 250)
            expect(p, f"WaitMoved({m})", c.wait_moved, m, 20_000)
            expect(p, f"GetAbsPos({m})", c.position, m, want=target)
            expect(p, f"SaveHome({m})", c.save_home, m)
            expect(p, f"MoveTo({m}, 150)", c.move_to, m, 150, 250)
            expect(p, f"WaitMoved({m})", c.wait_moved, m, 20_000)
            point = expect(p, f"SaveWayPoint({m})", c.save_waypoint, m)
            expect(p, f"GoHome({m})", c.go_home, m)
            expect(p, f"WaitMoved({m})", c.wait_moved, m, 20_000)
            expect(p, f"GetAbsPos({m}) at home", c.position, m, want=target)
            if isinstance(point, int):
                expect(p, f"MoveToWayPoint({m}, {point})", c.move_to_waypoint, m, point, 250)
                expect(p, f"WaitMoved({m})", c.wait_moved, m, 20_000)
                expect(p, f"GetAbsPos({m}) at waypoint {point}", c.position, m, want=150)
            expect(p, f"Move({m})", c.move, m, False, 1)
            expect(p, f"IsReady({m}) moving", c.is_ready, m, want=False)
            expect(p, f"StopMove({m}) soft", c.stop, m)
            expect(p, f"WaitMoved({m}) after a soft stop", c.wait_moved, m, 20_000)
            expect(p, f"Move({m}) again", c.move, m, True, 1)
            expect(p, f"StopMove({m}) hard", c.stop, m, True)
            expect(p, f"IsReady({m}) after a hard stop", c.is_ready, m, want=True)
            expect(p, f"InitMove({m})", c.init_move, m, False, 4)
            expect(p, f"WaitMoved({m}) homing", c.wait_moved, m, 30_000)
            expect(p, f"GetAbsPos({m}) homed", c.position, m, want=0)
            expect(
                p,
                f"MoveToWayPoint({m}, 9)",
                c.move_to_waypoint,
                m,
                9,
                error=ErrorCode.INVALID_WAYPOINT,
            )
        for pin in range(4):
            for high in (True, False):
                expect(p, f"SetPin({pin}, {high})", c.set_pin, pin, high)
                expect(p, f"GetPin({pin + 4})", c.get_pin, pin + 4, want=high)
        expect(p, "SetPin(5) on an input", c.set_pin, 5, True, error=ErrorCode.INVALID_COMMAND)
        expect(p, "DC forward 200 ms", c.dc_move, True, 200, False)
        expect(p, "DC reverse 100 ms", c.dc_move, False, 100, True)
        expect(p, "MoveTo(5)", c.move_to, 5, 0, error=ErrorCode.INVALID_ADDRESS)
        expect(p, "GetAbsPos(7)", c.position, 7, error=ErrorCode.INVALID_ADDRESS)
    return p


def run_fast(d: Daemon, seconds: float) -> list[str]:
    """3 motors at 25,000 step/s for ``seconds``, then a soft StopMove each."""
    p: list[str] = []
    with Client(str(d.pty), timeout=10.0) as c:
        for m in range(3):
            expect(p, f"Move({m}) at 25,000 step/s", c.move, m, m % 2 == 0, FAST_SPEED)
        end = time.monotonic() + seconds
        while time.monotonic() < end:  # a host polling now and then
            for m in range(3):
                expect(p, f"IsReady({m}) running", c.is_ready, m, want=False)
            time.sleep(0.25)
        for m in range(3):
            expect(p, f"StopMove({m}) soft", c.stop, m)
        for m in range(3):
            expect(p, f"WaitMoved({m})", c.wait_moved, m, 20_000)
            expect(
                p,
                f"GetAbsPos({m}) vs status",
                c.position,
                m,
                want=d.status()["motors"][m]["position"],
            )
    return p


# -- one run, one condition ------------------------------------------------------------------
def figures_of(statuses: list[dict[str, Any]], stderr: str) -> dict[str, Any]:
    motors = [m for st in statuses for m in st["motors"]]
    timing = [m.get("timing", {}) for m in motors]
    causes: dict[str, int] = {}
    for m in motors:
        for cause, n in m.get("faults", {}).items():
            causes[cause] = causes.get(cause, 0) + n
    faults = [
        line.split("fault latched: ", 1)[1]
        for line in stderr.splitlines()
        if "fault latched: " in line
    ]
    return {
        "late_absorbed": sum(t.get("late_absorbed", 0) for t in timing),
        "worst_late_us": max((t.get("worst_late_us", 0.0) for t in timing), default=0.0),
        "worst_lag_full_steps": max(
            (t.get("worst_lag_full_steps", 0.0) for t in timing), default=0.0
        ),
        "faults_by_cause": causes,
        "fault_texts": faults,
        "takeover_ms_max": max((m["soft_stops"]["takeover_ms"][1] for m in motors), default=0),
        "takeover_steps_max": max(
            (m["soft_stops"]["takeover_steps"][1] for m in motors), default=0
        ),
        "steps_max_us": max(st["steps"].get("max_us", 0) for st in statuses),
    }


def one_run(work: Path, rule: str, fast_s: float) -> dict[str, Any]:
    problems: list[str] = []
    statuses: list[dict[str, Any]] = []
    stderr = ""
    for part, fast in (("slow", False), ("fast", True)):
        folder = work / part
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        try:
            d = Daemon(folder, rule_config(rule, fast))
        except RuntimeError as exc:  # it did not start: that run failed
            problems.append(f"{part}: {exc}")
            continue
        try:
            if fast:
                problems += [f"fast: {x}" for x in run_fast(d, fast_s)]
            else:
                problems += [f"walkthrough: {x}" for x in run_walkthrough(d)]
                problems += [f"sweep: {x}" for x in run_sweep(d)]
            statuses.append(d.status())
        except (OSError, RuntimeError, DeviceError, subprocess.TimeoutExpired) as exc:
            problems.append(f"{part}: {type(exc).__name__}: {exc}")
        finally:
            code = d.stop()
            stderr += d.stderr()
            if code != 0:
                problems.append(f"{part}: motorctld exited {code}")
    out = figures_of(statuses, stderr) if statuses else {"fault_texts": [], "faults_by_cause": {}}
    e4 = error_text(ErrorCode.MOTOR_ERROR)
    out["e4"] = sum(1 for x in problems if e4 in x)
    out["problems"] = problems
    out["passed"] = not problems
    return out


@contextlib.contextmanager
def load(kind: str, work: Path) -> Iterator[None]:
    """Nothing, or two CPU hogs and a disk writer (fsync'd 256 MiB files, in a loop)."""
    procs: list[subprocess.Popen[bytes]] = []
    if kind == "loaded":
        for _ in range(2):
            procs.append(
                subprocess.Popen(["sh", "-c", "exec yes > /dev/null"], start_new_session=True)
            )
        target = work / "dd.out"
        procs.append(
            subprocess.Popen(
                [
                    "sh",
                    "-c",
                    f"while :; do dd if=/dev/zero of={target} bs=1M count=256 "
                    "conv=fsync status=none; done",
                ],
                start_new_session=True,
            )
        )
    try:
        yield
    finally:
        for proc in procs:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        with contextlib.suppress(FileNotFoundError):
            (work / "dd.out").unlink()


def cyclictest_max(seconds: float) -> int | None:
    """cyclictest -m -p 50 -i 1000 -t 2 for ``seconds``: its maximum latency (us). Run under
    the same load just before a condition's runs, not beside them: at the executor's
    priority it would compete with a busy-waiting executor for a CPU, and measure that."""
    exe = shutil.which("cyclictest")
    if exe is None or seconds <= 0:
        if exe is None:
            print("note: cyclictest not found (apt-get install rt-tests): no reference")
        return None
    out = subprocess.run(
        [exe, "-m", "-q", "-p", "50", "-i", "1000", "-t", "2", "-D", f"{seconds:.0f}"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    found = [int(x) for x in re.findall(r"Max:\s*(\d+)", out)]
    return max(found) if found else None


def condition(
    work: Path, load_kind: str, rule: str, runs: int, fast_s: float, cyclictest_s: float
) -> dict[str, Any]:
    results = []
    with load(load_kind, work):
        ct_max = cyclictest_max(cyclictest_s)
        for i in range(runs):
            r = one_run(work / "run", rule, fast_s)
            results.append(r)
            tag = "ok" if r["passed"] else f"{len(r['problems'])} problems"
            print(
                f"  {load_kind:6} {rule:4} run {i + 1:2}/{runs}: {tag}; late absorbed "
                f"{r.get('late_absorbed', 0)}, worst lag "
                f"{r.get('worst_lag_full_steps', 0):.3f} full steps, faults "
                f"{r['faults_by_cause'] or 'none'}",
                flush=True,
            )
            for x in r["problems"][:3]:
                print(f"      {x}")
    lag_faults = []
    other_faults = []
    for r in results:
        for text in r["fault_texts"]:
            m = LAG_FAULT.search(text)
            if m is None:
                other_faults.append(text)
            else:
                lag_faults.append(
                    {
                        "late_us": int(m.group(1)),
                        "speed": int(m.group(2)),
                        "lag": float(m.group(3)),
                        "tolerance": float(m.group(4)),
                    }
                )
    causes: dict[str, int] = {}
    for r in results:
        for cause, n in r["faults_by_cause"].items():
            causes[cause] = causes.get(cause, 0) + n
    return {
        "load": load_kind,
        "rule": rule,
        "runs": runs,
        "passed": sum(r["passed"] for r in results),
        "e4": sum(r["e4"] for r in results),
        "faults_by_cause": causes,
        "late_absorbed": sum(r.get("late_absorbed", 0) for r in results),
        "worst_late_us": max((r.get("worst_late_us", 0.0) for r in results), default=0.0),
        "worst_lag_full_steps": max(
            (r.get("worst_lag_full_steps", 0.0) for r in results), default=0.0
        ),
        "takeover_ms_max": max((r.get("takeover_ms_max", 0) for r in results), default=0),
        "takeover_steps_max": max((r.get("takeover_steps_max", 0) for r in results), default=0),
        "lag_faults": lag_faults,
        "lag_fault_speeds": sorted({f["speed"] for f in lag_faults}),
        "every_fault_a_lag_beyond_tolerance": not other_faults
        # (the text rounds the lag to 3 decimals: a lag just beyond shows as equal)
        and all(f["lag"] >= f["tolerance"] for f in lag_faults),
        "other_faults": other_faults,
        "cyclictest_max_us": ct_max,
        "problems": [x for r in results for x in r["problems"]][:20],
    }


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=20, help="fresh starts per condition")
    ap.add_argument("--loads", default="quiet,loaded", help="quiet, loaded or both")
    ap.add_argument("--rules", default="mock,real", help="mock, real or both")
    ap.add_argument(
        "--fast-seconds",
        type=float,
        default=10.0,
        help="how long 3 motors run at 25,000 step/s in each run",
    )
    ap.add_argument(
        "--cyclictest-seconds",
        type=float,
        default=30.0,
        help="cyclictest under each condition's load, before its runs (0: none)",
    )
    ap.add_argument(
        "--keep-rt-throttling",
        action="store_true",
        help="leave kernel.sched_rt_runtime_us as it is",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args()
    if os.geteuid() != 0:
        print("note: not root: motorctld runs without SCHED_FIFO, figures are best effort")
    with rt_throttling_off(not args.keep_rt_throttling) as old_rt:
        out: dict[str, Any] = {"sched_rt_runtime_us_before": old_rt, "conditions": []}
        with tempfile.TemporaryDirectory(
            dir=ROOT / "build" if (ROOT / "build").is_dir() else None
        ) as tmp:
            for load_kind in args.loads.split(","):
                for rule in args.rules.split(","):
                    out["conditions"].append(
                        condition(
                            Path(tmp),
                            load_kind,
                            rule,
                            args.runs,
                            args.fast_seconds,
                            args.cyclictest_seconds,
                        )
                    )
    print(
        "\nlateness judged as the motor would feel it "
        f"(sched_rt_runtime_us -1 during the run, {old_rt} before):"
    )
    for c in out["conditions"]:
        print(
            f"  {c['load']:6} {c['rule']:4}: {c['passed']}/{c['runs']} runs passed, "
            f"E4 {c['e4']}, faults {c['faults_by_cause'] or 'none'}, late steps absorbed "
            f"{c['late_absorbed']}, worst lateness {c['worst_late_us']:,.0f} us, worst lag "
            f"{c['worst_lag_full_steps']:.3f} full steps, soft stop take-over <= "
            f"{c['takeover_ms_max']} ms / {c['takeover_steps_max']} steps; cyclictest max "
            f"{c['cyclictest_max_us']} us"
        )
        if c["rule"] == "real":
            print(
                f"         lag faults at {c['lag_fault_speeds'] or 'no'} step/s; every fault "
                f"a lag beyond the tolerance: {c['every_fault_a_lag_beyond_tolerance']}"
            )
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
