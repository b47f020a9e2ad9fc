"""What reading motorctld's status costs the daemon while 3 motors step: CPU per read, the
rate a reader reaches, and what a live monitor costs.

A real daemon (bench/steps.py's, without real-time priority or a pinned CPU) runs 3 motors
at --rate step/s each. Four windows of --seconds each, on that one daemon:

  idle     nobody reads: the daemon's own CPU with the motors stepping (the baseline)
  reads    this process reads the status socket with ``read_status``, paced at --per-s
           reads a second (a read, then sleep until the next slot if there is time left;
           ``--per-s 0``: back to back, the ceiling): the rate reached, the per-read latency
           (connect to JSON parsed) p50/p99/max, and the daemon's CPU per read, "gross"
           (its CPU over the window over the reads) and "net" (less the idle window's rate:
           what the reads themselves cost)
  kept     the same, over one kept connection (``StatusReader``, the ``keep`` request:
           docs/status.md): a frequent reader's cheaper form, beside the per-connection
           figures (``kept_*`` in --json; ``--no-kept`` leaves it out)
  monitor  ``motorctl monitor --period 100`` (10 updates a second while the motors move) on
           a terminal of its own (a PTY of 120 x 50, drained as a terminal would): the
           daemon's CPU above the idle window, the monitor process's own, and the bytes a
           second it writes to its terminal; then once more with the motors stopped (at
           rest: the daemon sends an update only when something changed)

The daemon's CPU is its user + system time from /proc/PID/stat (every thread of it; the
process executor's own process not counted: it steps the same with or without readers);
the monitor's is the time its threads ran (/proc/PID/task/*/schedstat, in ns: a tick of
/proc/PID/stat is 10 ms, 0.2 % of a CPU over a 5 s window).
Targets (issue 36): at most 0.1 ms of the daemon's CPU per read at 1,000 reads a second;
the monitor at 10 Hz under 1 % of a CPU.

Not a step-timing benchmark: bench/steps.py measures what the reads do to the steps (on a
quiet machine, with real-time priority). ``--json FILE`` writes the figures (flat keys).
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import os
import pty
import shutil
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.steps import config_text  # noqa: E402  (the daemon of its status scenario)
from motorctl.daemon.status.reader import StatusReader, read_status  # noqa: E402
from tests.support.daemon_proc import DaemonProcess  # noqa: E402

READ_TARGET_MS = 0.1
MONITOR_TARGET_PERCENT = 1.0
MONITOR_PERIOD_MS = 100


def quantile(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return 0.0
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` (its threads; not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_s(pid: int) -> float:
    """The time process ``pid``'s threads have run (/proc/PID/task/*/schedstat: in ns,
    where /proc/PID/stat counts in clock ticks of 10 ms: too coarse for a process that
    takes under 1 % of a CPU)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            total += int((task / "schedstat").read_text().split()[0])
    return total / 1e9


def read_paced(
    sock: Path, seconds: float, per_s: int, kept: bool = False
) -> tuple[int, float, list[float], int]:
    """(reads, elapsed s, per-read latencies in s, bytes of the last document); ``kept``:
    over one kept connection (the first read connects)."""
    reader = StatusReader(sock) if kept else None

    def read() -> dict[str, Any]:
        return reader.read() if reader is not None else read_status(sock)

    period = 1.0 / per_s if per_s else 0.0
    lat: list[float] = []
    size = 0
    t0 = time.monotonic()
    end = t0 + seconds
    nxt = t0
    while time.monotonic() < end:
        a = time.perf_counter()
        doc = read()
        lat.append(time.perf_counter() - a)
        if not size:
            size = len(json.dumps(doc, sort_keys=True))
        if period:
            nxt += period
            d = nxt - time.monotonic()
            if d > 0:
                time.sleep(d)
    elapsed = time.monotonic() - t0
    if reader is not None:
        assert reader.connects == 1, f"the kept connection was made {reader.connects} times"
        reader.close()
    return len(lat), elapsed, lat, size


def idle_window(pid: int, seconds: float) -> float:
    """The daemon's CPU (s of CPU per s) while nobody reads."""
    cpu0, t0 = cpu_s(pid), time.monotonic()
    time.sleep(seconds)
    return (cpu_s(pid) - cpu0) / (time.monotonic() - t0)


def drain(fd: int, stop: threading.Event, count: list[int]) -> None:
    """Read what the monitor draws, as its terminal would, until it is gone; ``count[0]``:
    the bytes read so far."""
    while not stop.is_set():
        try:
            data = os.read(fd, 65536)
        except OSError:
            return
        if not data:
            return
        count[0] += len(data)


def monitor_window(state_dir: Path, seconds: float, daemon_pid: int) -> dict[str, float]:
    """``motorctl monitor --period 100`` on a PTY for ``seconds``: the daemon's CPU in the
    window and the monitor's (s of CPU a second), the bytes a second the monitor wrote to
    its terminal. The monitor's start-up is left out: the window begins once it has drawn
    its first view."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 50, 120, 0, 0))
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120", "LINES": "50"}
    cmd = [
        sys.executable,
        "-m",
        "motorctl.client.cli",
        "monitor",
        "--state-dir",
        str(state_dir),
        "--period",
        str(MONITOR_PERIOD_MS),
    ]
    proc = subprocess.Popen(
        cmd, stdin=slave, stdout=slave, stderr=slave, env=env, cwd=ROOT, start_new_session=True
    )
    os.close(slave)
    stop = threading.Event()
    first = threading.Event()
    written = [0]

    def follow() -> None:
        # the first bytes: it is up and drawing; then drain until it is gone
        try:
            if os.read(master, 65536):
                first.set()
        except OSError:
            return
        drain(master, stop, written)

    reader = threading.Thread(target=follow, daemon=True)
    reader.start()
    try:
        if not first.wait(30):
            raise RuntimeError("motorctl monitor drew nothing within 30 s")
        time.sleep(1.0)  # past its imports and its first full drawings
        d0, m0, t0, w0 = cpu_s(daemon_pid), run_s(proc.pid), time.monotonic(), written[0]
        time.sleep(seconds)
        d1, m1, t1, w1 = cpu_s(daemon_pid), run_s(proc.pid), time.monotonic(), written[0]
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        stop.set()
        os.close(master)
        reader.join(5)
    return {
        "daemon": (d1 - d0) / (t1 - t0),
        "monitor": (m1 - m0) / (t1 - t0),
        "bytes": (w1 - w0) / (t1 - t0),
    }


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
                pid = d.proc.pid
                before = d.status()["steps"]
                idle = idle_window(pid, args.seconds)
                cpu0 = cpu_s(pid)
                n, elapsed, lat, size = read_paced(
                    d.state_dir / "status.sock", args.seconds, args.per_s
                )
                cpu = cpu_s(pid) - cpu0
                kept = None
                if not args.no_kept:
                    kcpu0 = cpu_s(pid)
                    kn, kelapsed, klat, _ = read_paced(
                        d.state_dir / "status.sock", args.seconds, args.per_s, kept=True
                    )
                    kept = (kn, kelapsed, klat, cpu_s(pid) - kcpu0)
                monitor = (
                    None if args.no_monitor else monitor_window(d.state_dir, args.seconds, pid)
                )
                after = d.status()
                for m in range(3):
                    c.stop(m, hard=True)
                rest = None if args.no_monitor else monitor_window(d.state_dir, args.seconds, pid)
        finally:
            d.close()
            shutil.rmtree(work / "state", ignore_errors=True)
    lat.sort()
    moving = [m["state"] for m in after["motors"]]
    fig: dict[str, Any] = {
        "executor": args.executor,
        "target_reads_per_s": args.per_s,
        "reads": n,
        "reads_per_s": round(n / elapsed, 1),
        "read_p50_ms": round(quantile(lat, 0.5) * 1e3, 3),
        "read_p99_ms": round(quantile(lat, 0.99) * 1e3, 3),
        "read_max_ms": round(lat[-1] * 1e3, 3) if lat else 0.0,
        "status_bytes": size,
        "idle_daemon_cpu_percent": round(100 * idle, 2),
        "daemon_cpu_percent": round(100 * cpu / elapsed, 1),
        "cpu_ms_per_read": round(1e3 * cpu / max(1, n), 4),
        "net_cpu_ms_per_read": round(1e3 * (cpu - idle * elapsed) / max(1, n), 4),
        "read_target_ms": READ_TARGET_MS,
        "steps_in_window": after["steps"]["steps"] - before["steps"],
        "motor_states_at_end": ",".join(moving),
    }
    if kept is not None:
        kn, kelapsed, klat, kcpu = kept
        klat.sort()
        fig.update(
            kept_reads=kn,
            kept_reads_per_s=round(kn / kelapsed, 1),
            kept_read_p50_ms=round(quantile(klat, 0.5) * 1e3, 3),
            kept_read_p99_ms=round(quantile(klat, 0.99) * 1e3, 3),
            kept_read_max_ms=round(klat[-1] * 1e3, 3) if klat else 0.0,
            kept_daemon_cpu_percent=round(100 * kcpu / kelapsed, 1),
            kept_cpu_ms_per_read=round(1e3 * kcpu / max(1, kn), 4),
            kept_net_cpu_ms_per_read=round(1e3 * (kcpu - idle * kelapsed) / max(1, kn), 4),
        )
    if monitor is not None:
        fig.update(
            monitor_period_ms=MONITOR_PERIOD_MS,
            monitor_daemon_cpu_percent=round(100 * (monitor["daemon"] - idle), 2),
            monitor_own_cpu_percent=round(100 * monitor["monitor"], 2),
            monitor_bytes_per_s=round(monitor["bytes"]),
            monitor_target_percent=MONITOR_TARGET_PERCENT,
        )
    if rest is not None:
        fig.update(
            monitor_at_rest_own_cpu_percent=round(100 * rest["monitor"], 2),
            monitor_at_rest_bytes_per_s=round(rest["bytes"]),
        )
    return fig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0, help="length of each window")
    ap.add_argument(
        "--per-s", type=int, default=1000, help="target reads a second (0: back to back)"
    )
    ap.add_argument("--rate", type=int, default=10000, help="step/s per motor")
    ap.add_argument("--executor", default="process", choices=("process", "thread"))
    ap.add_argument("--no-monitor", action="store_true", help="leave out the monitor's window")
    ap.add_argument("--no-kept", action="store_true", help="leave out the kept connection's window")
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON (flat keys)")
    args = ap.parse_args()
    fig = measure(args)
    print(
        f"status reads against a daemon ({fig['executor']} executor, 3 motors x "
        f"{args.rate} step/s, {fig['steps_in_window']} steps in the window; load "
        f"{os.getloadavg()[0]:.2f}):"
    )
    print(
        f"  {fig['reads_per_s']} reads/s (target {args.per_s or 'back to back'}), "
        f"per read p50 {fig['read_p50_ms']} ms, p99 {fig['read_p99_ms']} ms, "
        f"max {fig['read_max_ms']} ms; {fig['status_bytes']} bytes a document"
    )
    print(
        f"  the daemon's CPU: {fig['idle_daemon_cpu_percent']} % of a CPU without readers, "
        f"{fig['daemon_cpu_percent']} % while read: {fig['cpu_ms_per_read']} ms a read, "
        f"{fig['net_cpu_ms_per_read']} ms a read above the motors' own (target <= "
        f"{READ_TARGET_MS} ms; the process executor's own process not counted)"
    )
    if "kept_reads" in fig:
        print(
            f"  over one kept connection ('keep'): {fig['kept_reads_per_s']} reads/s, per read "
            f"p50 {fig['kept_read_p50_ms']} ms, p99 {fig['kept_read_p99_ms']} ms; the daemon's "
            f"CPU {fig['kept_daemon_cpu_percent']} %: {fig['kept_cpu_ms_per_read']} ms a read, "
            f"{fig['kept_net_cpu_ms_per_read']} ms above the motors' own (one connection a "
            f"read: {fig['net_cpu_ms_per_read']} ms)"
        )
    if "monitor_daemon_cpu_percent" in fig:
        print(
            f"  motorctl monitor --period {MONITOR_PERIOD_MS} on a terminal: the daemon "
            f"{fig['monitor_daemon_cpu_percent']} % of a CPU above the motors' own, the "
            f"monitor itself {fig['monitor_own_cpu_percent']} % (target < "
            f"{MONITOR_TARGET_PERCENT:.0f} %), writing {fig['monitor_bytes_per_s']:,} bytes/s"
        )
    if "monitor_at_rest_own_cpu_percent" in fig:
        print(
            f"  the same with every motor at rest: the monitor itself "
            f"{fig['monitor_at_rest_own_cpu_percent']} % of a CPU, writing "
            f"{fig['monitor_at_rest_bytes_per_s']:,} bytes/s"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
