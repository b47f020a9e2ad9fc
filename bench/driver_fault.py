"""Fault to E4: how long after a driver chip reports a fault the host's next command gets E4.

A real daemon (motorctld as a process, the mock backend) drives one motor whose TMC2130
sits behind the stand-in py-spidev of tests/fakespi/ (the register-level chip model of
tests/support/tmc_model.py). Each run waits a random 0..``--spread-ms`` (so that the fault
falls anywhere in the poll schedule), sets the chip's over-temperature flag (the stand-in's
control file, tests/support/stand_ins.py ``set_chips``) and from that moment sends
IsReady(0) every ``--interval-ms`` until one is answered E4: the time from setting the
flag to that answer is the run's figure. Then the flag is cleared and a hard StopMove
repeated until it is taken (the fault cleared), and the next run begins. The motor stands
still: the figure is the driver poll's, not the step path's.

What it measures is what the daemon's polling gives: the chip model answers at once, so a
fault is seen at the first DRV_STATUS read after it was set, and acted on when that read's
news reaches the motor's state machine.

``--tree NAME=DIR`` (repeatable) runs a daemon from each source tree (a checkout of another
commit, its compiled step core built or copied in), all at the same time, and interleaves
their runs round by round in a shuffled order, so that each sees the same machine; without
it, one daemon from this tree. The daemons run with the keys' defaults but real-time
priority, which a shared machine does not give (``--config-extra`` adds TOML to each
config). ``--json FILE`` writes the figures (flat keys, per tree).

What the polling costs: before the runs, all daemons idle together for ``--idle-s``
seconds, and each one's CPU time over that window is printed as a percentage of one CPU
(the daemon's process, its threads: the driver poll's thread among them; not the step
executor's own process).

The machine's load average is printed (and written) at the start and the end: on a loaded
machine the tail grows with the scheduler's delays, whatever the poll does.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motorctl.client.client import Client, DeviceError  # noqa: E402
from motorctl.protocol.codec import ErrorCode  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402
from tests.support.stand_ins import set_chips, stand_in_env  # noqa: E402
from tests.support.tmc_model import OT  # noqa: E402

CONFIG = """\
[step_thread]
priority = 0
lock_memory = false

[[motors]]
name = "x"
[motors.tmc]
driver = "tmc2130"
spi = "/dev/spidev0.0"
"""
CHIPS = {"0.0": "tmc2130"}
#: a run that sees no E4 within this long is a failure of the daemon, not a figure
GIVE_UP_S = 5.0


@dataclass
class Subject:
    """One daemon under test: its source tree, its process, its chip's control file."""

    name: str
    tree: Path
    daemon: DaemonProcess
    control: Path
    client: Client
    times: list[float] = field(default_factory=list)


def start(name: str, tree: Path, workdir: Path, extra: str) -> Subject:
    """A daemon of ``tree`` (run with that tree as its working directory, so that
    ``python -m motorctl...`` imports that tree's motorctl) with the stand-in py-spidev."""
    workdir.mkdir(parents=True)
    control = workdir / "control.json"
    env = stand_in_env("spidev", chips=CHIPS, control=control)
    prefix = [] if tree == ROOT else ["env", "-C", str(tree)]
    daemon = DaemonProcess(workdir, CONFIG + extra, env=env, as_user=True, prefix=prefix).start()
    return Subject(name, tree, daemon, control, daemon.client())


def cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` (its threads; not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def idle_cpu(subjects: list[Subject], seconds: float) -> dict[str, float]:
    """Each daemon's CPU use (% of one CPU) over one window in which all of them idle."""
    pids = {s.name: s.daemon.proc.pid for s in subjects if s.daemon.proc is not None}
    before = {name: cpu_s(pid) for name, pid in pids.items()}
    t0 = time.monotonic()
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    return {name: 100 * (cpu_s(pid) - before[name]) / elapsed for name, pid in pids.items()}


def until_taken(c: Client, give_up: float) -> None:
    """A hard StopMove of motor 0 until it is taken (the latched fault cleared)."""
    while True:
        try:
            c.stop(0, hard=True)
            return
        except DeviceError:
            if time.monotonic() > give_up:
                raise RuntimeError("the fault did not clear") from None
            time.sleep(0.002)


def seconds_to_e4(c: Client, motor: int, name: str, t0: float, interval_s: float) -> float:
    """IsReady(``motor``) every ``interval_s`` until E4; the seconds since ``t0`` (the fault
    set). bench/dspin.py measures its chips' faults with it too."""
    while True:
        try:
            c.is_ready(motor)
        except DeviceError as exc:
            if exc.code is not ErrorCode.MOTOR_ERROR:
                raise
            return time.monotonic() - t0
        if time.monotonic() - t0 > GIVE_UP_S:
            raise RuntimeError(f"{name}: no E4 within {GIVE_UP_S} s of the fault")
        time.sleep(interval_s)


def one_run(s: Subject, interval_s: float) -> float:
    """Set the fault, IsReady(0) until E4; the seconds in between. Then clear it."""
    set_chips(s.control, {"0.0": {"faults": [OT]}})
    t0 = time.monotonic()
    try:
        return seconds_to_e4(s.client, 0, s.name, t0, interval_s)
    finally:
        set_chips(s.control, {"0.0": {"faults": []}})
        until_taken(s.client, time.monotonic() + GIVE_UP_S)


def quantile(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))] if v else 0.0


def figures(
    subjects: list[Subject], load: tuple[list[float], list[float]], cpu: dict[str, float]
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "runs": len(subjects[0].times) if subjects else 0,
        "loadavg_start": [round(x, 2) for x in load[0]],
        "loadavg_end": [round(x, 2) for x in load[1]],
    }
    for s in subjects:
        t = [x * 1e3 for x in s.times]
        out.update(
            {
                f"{s.name}_p50_ms": round(quantile(t, 0.5), 2),
                f"{s.name}_p90_ms": round(quantile(t, 0.9), 2),
                f"{s.name}_p99_ms": round(quantile(t, 0.99), 2),
                f"{s.name}_mean_ms": round(sum(t) / len(t), 2) if t else 0.0,
                f"{s.name}_min_ms": round(min(t), 2) if t else 0.0,
                f"{s.name}_max_ms": round(max(t), 2) if t else 0.0,
                f"{s.name}_idle_cpu_percent": round(cpu.get(s.name, 0.0), 2),
            }
        )
    return out


def measure(args: argparse.Namespace, trees: list[tuple[str, Path]]) -> dict[str, Any]:
    rng = random.Random(args.seed)
    tmp = Path(tempfile.mkdtemp(prefix="motorctl-fault-"))
    subjects: list[Subject] = []
    try:
        for name, tree in trees:
            subjects.append(start(name, tree, tmp / name, args.config_extra))
        load_start = list(os.getloadavg())
        cpu = idle_cpu(subjects, args.idle_s)
        for s in subjects:  # one run each, not counted: imports and first polls warm up
            time.sleep(0.1)
            one_run(s, args.interval_ms / 1e3)
        for _ in range(args.runs):
            order = list(subjects)
            rng.shuffle(order)
            for s in order:
                time.sleep(rng.uniform(0.0, args.spread_ms / 1e3))
                s.times.append(one_run(s, args.interval_ms / 1e3))
        load_end = list(os.getloadavg())
    finally:
        for s in subjects:
            with contextlib.suppress(Exception):
                s.client.close()
            s.daemon.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return figures(subjects, (load_start, load_end), cpu)


def parse_trees(given: list[str]) -> list[tuple[str, Path]]:
    if not given:
        return [("this", ROOT)]
    out = []
    for item in given:
        name, sep, where = item.partition("=")
        tree = Path(where).resolve()
        if not sep or not name.isidentifier() or not (tree / "motorctl").is_dir():
            raise SystemExit(f"--tree {item!r}: write NAME=DIR, DIR a motorctl source tree")
        out.append((name, tree))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=200, help="runs per daemon")
    ap.add_argument("--interval-ms", type=float, default=1.0, help="between the host's IsReady")
    ap.add_argument("--spread-ms", type=float, default=100.0, help="random wait before a fault")
    ap.add_argument("--tree", action="append", default=[], help="NAME=DIR: a daemon of DIR")
    ap.add_argument("--config-extra", default="", help="TOML added to every daemon's config")
    ap.add_argument("--idle-s", type=float, default=5.0, help="the idle window for CPU use")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON (flat keys)")
    args = ap.parse_args()
    trees = parse_trees(args.tree)
    fig = measure(args, trees)
    print(
        f"fault to E4 (TMC2130 model, motor at rest, IsReady every {args.interval_ms} ms), "
        f"{fig['runs']} runs each, load average {fig['loadavg_start']} -> {fig['loadavg_end']}:"
    )
    for name, tree in trees:
        print(
            f"  {name} ({tree}): p50 {fig[f'{name}_p50_ms']} ms, p90 {fig[f'{name}_p90_ms']} ms, "
            f"p99 {fig[f'{name}_p99_ms']} ms, mean {fig[f'{name}_mean_ms']} ms, "
            f"min {fig[f'{name}_min_ms']} ms, max {fig[f'{name}_max_ms']} ms; "
            f"idle: {fig[f'{name}_idle_cpu_percent']} % of a CPU"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
