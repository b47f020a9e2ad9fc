"""The delay ``motorctl tap`` adds: IsReady-sized round trips through the tap against the same
echo device reached straight, both on PTYs at 115,200 baud, interleaved rounds.

Straight: host -> PTY -> echo device. Tapped: host -> PTY -> tap -> PTY -> echo device (a
second one, the same program). The
added delay is the tapped round trip minus the straight one (p50, p99; a round trip crosses
the tap twice), besides the tap's own figure (poll() returning with the bytes to their write
returning, per run). A PTY has no wire time: on real UARTs at 115,200 baud each 10-byte
frame also spends 868 us on each wire, which the tap (forwarding every run as it is read)
does not wait for in full. ``--json FILE`` writes the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.echo_peer import echo  # noqa: E402  (the echo peer's loop: REPLY per 10 bytes)

FRAME = bytes.fromhex("03 00 00 00 00 00 00 00 00 8b")
WARM_UP = 50


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))]


def echo_device() -> tuple[int, str]:
    """A PTY whose master answers IsReady's TRUE per 10 bytes (a child process): its slave."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    name = os.ttyname(slave)
    pid = os.fork()
    if pid == 0:  # the device; it keeps the slave open, so its reads never fail with EIO
        echo(master)
    os.close(master)
    os.close(slave)
    return pid, name


def round_trips(fd: int, n: int) -> list[float]:
    times = []
    for i in range(WARM_UP + n):
        t0 = time.perf_counter()
        os.write(fd, FRAME)
        got = b""
        while len(got) < 5:
            if not select.select([fd], [], [], 2.0)[0]:
                raise RuntimeError("no reply within 2 s")
            got += os.read(fd, 5 - len(got))
        if i >= WARM_UP:
            times.append(time.perf_counter() - t0)
    return times


def summary(times: list[float]) -> dict[str, float]:
    return {
        "p50_us": round(pct(times, 50) * 1e6, 1),
        "p99_us": round(pct(times, 99) * 1e6, 1),
        "max_us": round(max(times) * 1e6, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=1000, help="round trips per path and round")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    work = Path(os.environ.get("TMPDIR", "/tmp"))
    # two identical echo devices: a port read by the tap cannot also be read straight
    straight_pid, straight_port = echo_device()
    device_pid, device_port = echo_device()
    straight = os.open(straight_port, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(straight)
    host, host_slave = os.openpty()
    tty.setraw(host)
    tty.setraw(host_slave)
    host_port = os.ttyname(host_slave)
    os.close(host_slave)
    out = work / f"bench-tap-{os.getpid()}.pcapng"
    tap = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "motorctl.client.cli",
            "tap",
            "--host",
            host_port,
            "--device",
            device_port,
            "--out",
            str(out),
            "--baud",
            "115200",
            "--json",
        ],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        assert tap.stdout is not None
        tap.stdout.readline()
        straight_t: list[float] = []
        tapped_t: list[float] = []
        for _ in range(args.rounds):
            straight_t += round_trips(straight, args.n)
            try:
                tapped_t += round_trips(host, args.n)
            except OSError:
                tap.send_signal(signal.SIGTERM)
                raise RuntimeError(f"the tap stopped: {tap.communicate(timeout=30)[0]}") from None
        tap.send_signal(signal.SIGTERM)
        report: dict[str, Any] = json.loads(tap.communicate(timeout=30)[0])
    finally:
        if tap.poll() is None:
            tap.kill()
        for pid in (straight_pid, device_pid):
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        out.unlink(missing_ok=True)
    s, t = summary(straight_t), summary(tapped_t)
    result = {
        "baud": 115200,
        "round_trips_each": len(straight_t),
        "straight": s,
        "tapped": t,
        "added_p50_us": round(t["p50_us"] - s["p50_us"], 1),
        "added_p99_us": round(t["p99_us"] - s["p99_us"], 1),
        "tap_internal_delay_us": report["added_delay_us"],
        "load_avg_1min": os.getloadavg()[0],
    }
    print(f"IsReady-sized round trips over PTYs at 115200 baud, {len(straight_t)} each:")
    for name, r in (("straight", s), ("via tap", t)):
        print(
            f"  {name:<9} p50 {r['p50_us']:8.1f} us  p99 {r['p99_us']:8.1f} us  "
            f"max {r['max_us']:.0f} us"
        )
    d = report["added_delay_us"]
    print(
        f"  added by the tap (round trip, two crossings): p50 {result['added_p50_us']} us, "
        f"p99 {result['added_p99_us']} us"
    )
    print(
        f"  the tap's own read-to-write delay per run: p50 {d['p50']} us, p99 {d['p99']} us,"
        f" max {d['max']} us  (load average {result['load_avg_1min']:.2f})"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
