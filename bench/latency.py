"""IsReady round trips through motorctld's PTY against a bare echo peer on a PTY, same run.

Prints p50/p99 of both and their ratio, the CPU time each spends per round trip (the
daemon: its link thread), and the daemon's own processing time per command
(last byte read to reply written, measured inside the daemon). Targets: round-trip p99
<= 2x the echo peer's (idle), <= 1.5x while 3 motors step (``--motion 25000``, issue 7: the
link must not feel the motion); processing p99 <= 108 us.

``--parts``: the daemon counts its link thread's CPU time part by part (read, decode,
dispatch, encode, write, the poll and the session's bookkeeping: daemon/link/cpu_parts.py,
``MOTORCTL_LINK_CPU_PARTS=1``), printed per round trip beside the echo peer's whole CPU per
round trip. The count's own clock readings (7 a round trip, a system call each) are in the
daemon's figures then: compare the total without ``--parts``.

``--trace``: a second motorctld, the same but with ``--trace`` (its link's byte runs recorded
to a pcapng file), takes its turns too; its round trips against the untraced daemon's give
the cost of the trace (issue 18: p99 <= 1.1x).

The floor: a third peer (``echo_peer.py --as-link``) that makes the link's system calls a
turn in Python and does nothing else; its CPU per round trip against the echo peer's is what
a link thread in Python cannot go below, and what is left of the 2x target beside it is what
decoding, dispatching, encoding and the bookkeeping may spend.

``--cpus D,H``: every peer on CPU ``D``, the host on CPU ``H`` (as bench/reconnect.py's). Where
the kernel wakes a peer decides much of its CPU per round trip (a wake-up on the host's CPU,
a migration), differently for a one-thread peer and the daemon: pinned, the three are
compared on equal terms.

The peers take turns in short rounds (``--rounds`` of ``-n``), so the machine's drifts
(another tenant, a busy spell) hit both alike; with motion, both run beside the stepping
daemon (its step process spinning on one CPU, its planner on the other).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import serial

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.reconnect import cpu_pair, pin_tree  # noqa: E402
from motorctl.daemon.start.link_parts import CPU_PARTS_ENV  # noqa: E402
from motorctl.daemon.status.reader import read_status  # noqa: E402
from motorctl.protocol.codec import CodecOptions, IsReady, encode_command  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))]


WARM_UP = 50  # round trips before each round's measured ones


def round_trips(port: str, n: int, frame: bytes) -> list[float]:
    times = []
    with serial.Serial(port, 115200, timeout=2) as s:
        for _ in range(WARM_UP):
            s.write(frame)
            s.read(5)
        for _ in range(n):
            t0 = time.perf_counter()
            s.write(frame)
            got = s.read(5)
            times.append(time.perf_counter() - t0)
            if len(got) != 5:
                raise RuntimeError(f"short reply from {port}: {got!r}")
    return times


def cpu_s(pid: int) -> float:
    """CPU time of ``pid``'s main thread so far: the daemon's link thread, the echo peer's
    only one. The scheduler's own count (``schedstat``, nanoseconds): ``stat``'s user and
    system times are sampled at clock ticks (10 ms), a sixth of the echo peer's CPU in a
    round of 1,000."""
    return int(Path(f"/proc/{pid}/task/{pid}/schedstat").read_text().split()[0]) / 1e9


def link_parts(daemon: DaemonProcess) -> dict[str, int]:
    """The daemon's link thread's CPU nanoseconds so far, by part (``--parts``)."""
    parts: dict[str, Any] = daemon.status()["link"]["cpu_parts"]
    return {part: int(ns) for part, ns in parts["ns"].items()}


def summary(times: list[float]) -> dict[str, float]:
    return {
        "p50_us": round(pct(times, 50) * 1e6, 1),
        "p99_us": round(pct(times, 99) * 1e6, 1),
        "max_us": round(max(times) * 1e6, 1),
        "mean_us": round(statistics.mean(times) * 1e6, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=1000, help="round trips per peer and round")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument(
        "--motion",
        type=int,
        default=0,
        metavar="STEPS_PER_S",
        help="run 3 motors at this many step/s each during the daemon's rounds "
        "(issue 7: 25000); the echo peer's rounds are the reference",
    )
    ap.add_argument("--executor", default="process", choices=("process", "thread"))
    ap.add_argument(
        "--switch-interval-us",
        type=float,
        metavar="US",
        help="[step_thread] switch_interval_us for the daemon with --motion (default: its own)",
    )
    ap.add_argument(
        "--trace",
        action="store_true",
        help="also a daemon with --trace: the trace's cost (target p99 <= 1.1x)",
    )
    ap.add_argument(
        "--parts",
        action="store_true",
        help="the daemon's link thread's CPU per round trip, part by part (its clock readings "
        "add to it)",
    )
    ap.add_argument(
        "--cpus",
        metavar="D,H",
        help="every peer (the echo peer, the floor, each daemon with every thread of it and of "
        "its step process) on CPU D, the host (this process) on CPU H; without it the kernel "
        "places them, and where it wakes a peer decides much of its CPU per round trip",
    )
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    cpus = cpu_pair(ap, args.cpus)
    frame = encode_command(IsReady(0), CodecOptions())
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        echo_link = work / "echo.pty"
        echo = subprocess.Popen(
            [sys.executable, str(ROOT / "bench" / "echo_peer.py"), str(echo_link)],
            stdout=subprocess.PIPE,
        )
        floor_link = work / "floor.pty"
        floor = subprocess.Popen(
            [sys.executable, str(ROOT / "bench" / "echo_peer.py"), str(floor_link), "--as-link"],
            stdout=subprocess.PIPE,
        )
        for peer in (echo, floor):
            assert peer.stdout is not None
            peer.stdout.readline()
        config = None
        if args.motion:
            from bench.steps import config_text

            extra = (
                ""
                if args.switch_interval_us is None
                else f"switch_interval_us = {args.switch_interval_us}"
            )
            # run_speed_factor 1000: SPEED kHz
            config = config_text(50, 0, args.executor, step_thread=extra)
        env = {CPU_PARTS_ENV: "1"} if args.parts else None
        daemon = DaemonProcess(work, config, env=env).start()
        traced: DaemonProcess | None = None
        try:
            if args.trace:
                (work / "traced").mkdir()
                traced = DaemonProcess(
                    work / "traced", config, extra=["--trace", str(work / "trace.pcapng")]
                ).start()
            for d in (daemon, traced):
                if args.motion and d is not None:
                    with d.client() as c:
                        for m in range(3):
                            c.move(m, True, speed=args.motion // 1000)
            if args.motion:
                time.sleep(0.5)
            echo_t: list[float] = []
            floor_t: list[float] = []
            daemon_t: list[float] = []
            traced_t: list[float] = []
            assert daemon.proc is not None
            cpu = {"echo": 0.0, "floor": 0.0, "daemon": 0.0, "traced": 0.0}
            peers: list[tuple[str, int, Path, list[float]]] = [
                ("echo", echo.pid, echo_link, echo_t),
                ("floor", floor.pid, floor_link, floor_t),
                ("daemon", daemon.proc.pid, daemon.pty, daemon_t),
            ]
            if traced is not None:
                assert traced.proc is not None
                peers.append(("traced", traced.proc.pid, traced.pty, traced_t))
            if cpus is not None:
                for peer_pid in (echo.pid, floor.pid, daemon.proc.pid):
                    pin_tree(peer_pid, cpus[0])
                if traced is not None and traced.proc is not None:
                    pin_tree(traced.proc.pid, cpus[0])
                os.sched_setaffinity(0, {cpus[1]})
            parts_before = link_parts(daemon) if args.parts else None
            for _ in range(args.rounds):  # interleaved rounds: drift hits all alike
                for name, pid, port, into in peers:
                    before = cpu_s(pid)
                    into += round_trips(str(port), args.n, frame)
                    cpu[name] += cpu_s(pid) - before
            status = read_status(daemon.state_dir / "status.sock")
            parts_after = link_parts(daemon) if args.parts else None
            trace_status = None if traced is None else read_status(traced.state_dir / "status.sock")
        finally:
            daemon.close()
            if traced is not None:
                traced.close()
            for peer in (echo, floor):
                peer.kill()
                peer.wait()
    result: dict[str, Any] = {
        "echo_peer": summary(echo_t),
        "daemon": summary(daemon_t),
        "processing": status["link"]["processing"],
    }
    result["p99_ratio"] = round(result["daemon"]["p99_us"] / result["echo_peer"]["p99_us"], 2)
    # With motion, both peers share one CPU with the client: a round trip costs the CPU
    # work of both ends, wherever in its loop a peer spends it.
    made = args.rounds * (args.n + WARM_UP)  # per peer, the warm-ups included
    result["echo_cpu_per_round_trip_us"] = round(cpu["echo"] / made * 1e6, 1)
    result["daemon_cpu_per_round_trip_us"] = round(cpu["daemon"] / made * 1e6, 1)
    result["cpu_ratio"] = round(cpu["daemon"] / cpu["echo"], 2) if cpu["echo"] else None
    result["floor"] = summary(floor_t)
    result["floor_cpu_per_round_trip_us"] = round(cpu["floor"] / made * 1e6, 1)
    result["floor_cpu_ratio"] = round(cpu["floor"] / cpu["echo"], 2) if cpu["echo"] else None
    if parts_before is not None and parts_after is not None:
        result["daemon_cpu_parts_us"] = {
            part: round((parts_after[part] - parts_before[part]) / made / 1000, 2)
            for part in parts_after
        }
    result["cpus"] = None if cpus is None else {"peers": cpus[0], "host": cpus[1]}
    result["motion_steps_per_s_per_motor"] = args.motion
    result["executor"] = args.executor
    result["switch_interval_us"] = args.switch_interval_us
    result["daemon_p99_us"] = result["daemon"]["p99_us"]
    result["echo_p99_us"] = result["echo_peer"]["p99_us"]
    result["p50_ratio"] = round(result["daemon"]["p50_us"] / result["echo_peer"]["p50_us"], 2)
    e, d, p = result["echo_peer"], result["daemon"], result["processing"]
    where = "" if cpus is None else f" (the peers on CPU {cpus[0]}, the host on CPU {cpus[1]})"
    print(f"IsReady round trip over a PTY, {len(daemon_t)} each{where}:")
    for name, r in (("echo peer", e), ("motorctld", d)):
        print(
            f"  {name:<10} p50 {r['p50_us']:8.1f} us  p99 {r['p99_us']:8.1f} us  "
            f"max {r['max_us']:.0f}"
        )
    target = 1.5 if args.motion else 2.0
    result["target_p99_ratio"] = target
    print(f"  ratio p50 {result['p50_ratio']}  p99 {result['p99_ratio']}  (target p99 <= {target})")
    print(
        f"  CPU per round trip: echo peer {result['echo_cpu_per_round_trip_us']} us, "
        f"motorctld's link thread {result['daemon_cpu_per_round_trip_us']} us "
        f"(ratio {result['cpu_ratio']}, target <= 2)"
    )
    print(
        f"  floor: the link's system calls alone, in Python (echo_peer.py --as-link) "
        f"{result['floor_cpu_per_round_trip_us']} us ({result['floor_cpu_ratio']}x the echo "
        f"peer): what is left of 2x for decoding, dispatching, encoding and the bookkeeping "
        f"{2 * result['echo_cpu_per_round_trip_us'] - result['floor_cpu_per_round_trip_us']:.1f} us"
    )
    if "daemon_cpu_parts_us" in result:
        parts = result["daemon_cpu_parts_us"]
        print(
            f"  the link thread's CPU per round trip by part ({sum(parts.values()):.1f} us "
            "with the count's own clock readings): "
            + ", ".join(f"{part} {us:.1f}" for part, us in parts.items())
        )
    print(f"daemon processing (last byte read -> reply written), {p['reads']} commands:")
    print(
        f"  p50 {p['p50_us']} us  p99 {p['p99_us']} us  p99.9 {p['p999_us']} us  "
        f"max {p['max_us']} us  (target p99 <= 108 us)"
    )
    if trace_status is not None:
        t = result["daemon_traced"] = summary(traced_t)
        result["trace_p50_ratio"] = round(t["p50_us"] / d["p50_us"], 2)
        result["trace_p99_ratio"] = round(t["p99_us"] / d["p99_us"], 2)
        result["traced_cpu_per_round_trip_us"] = round(cpu["traced"] / made * 1e6, 1)
        result["trace"] = trace_status["trace"]
        result["traced_processing"] = trace_status["link"]["processing"]
        print(
            f"with --trace ({trace_status['trace']['runs']} byte runs recorded, "
            f"{trace_status['trace']['dropped_runs']} dropped):"
        )
        print(
            f"  motorctld  p50 {t['p50_us']:8.1f} us  p99 {t['p99_us']:8.1f} us  "
            f"max {t['max_us']:.0f}"
        )
        print(
            f"  ratio to untraced: p50 {result['trace_p50_ratio']}  p99 "
            f"{result['trace_p99_ratio']}  (target p99 <= 1.1); CPU per round trip "
            f"{result['traced_cpu_per_round_trip_us']} us"
        )
    result["load_avg_1min"] = os.getloadavg()[0]
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
