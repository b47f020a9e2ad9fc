"""What durability costs on the command path: the motion journal and a full state write.

- ``journal``: MotionJournal.begin() for a motor at rest on disk, i.e. the pwrite of one
  byte + fdatasync that a motion command from rest pays before its ACK (a motor already
  moving pays nothing). Then end() and a clear, as the writer does once it is at rest.
- ``state``: StateWriter.write_now() of a state of 3 motors with N waypoints each, i.e.
  what SaveHome/SaveWayPoint pay before their ACK (temporary file, write, fsync, rename,
  fsync of the directory).

Run on a tmpfs (/dev/shm, like /run/motorctl) and on the disk (/var/tmp, like
/var/lib/motorctl). Prints a table; ``--json FILE`` writes the figures.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motorctl.daemon.state.journal import MotionJournal  # noqa: E402
from motorctl.daemon.state.records import SavedMotor, SavedState  # noqa: E402
from motorctl.daemon.state.writer import Snapshot, StateWriter  # noqa: E402


def percentiles(samples: list[float]) -> dict[str, float]:
    s = sorted(samples)
    return {
        "median_us": round(statistics.median(s) * 1e6, 1),
        "p99_us": round(s[int(len(s) * 0.99) - 1] * 1e6, 1),
        "max_us": round(s[-1] * 1e6, 1),
    }


def bench_journal(where: Path, n: int) -> dict[str, float]:
    j = MotionJournal(where / "state.moving", 3)
    j.reset()
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        j.begin(0)
        samples.append(time.perf_counter() - t0)
        j.end(0)
        j.clear_if_unchanged(0, j.token(0))
    j.close()
    return percentiles(samples)


def bench_state(where: Path, n: int, waypoints: int) -> dict[str, float]:
    motors = [
        SavedMotor(f"m{i}", "0123456789abcdef", 1000 * i, 0, list(range(waypoints)), False, False)
        for i in range(3)
    ]
    snap = Snapshot(SavedState(motors), {})
    writer = StateWriter(where / "state.json", lambda: snap)
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        assert writer.write_now()
        samples.append(time.perf_counter() - t0)
    return percentiles(samples)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-n", type=int, default=300, help="repetitions (default 300)")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = p.parse_args()
    out: dict[str, Any] = {}
    for label, base in (("tmpfs", "/dev/shm"), ("disk", "/var/tmp")):
        with tempfile.TemporaryDirectory(dir=base) as tmp:
            where = Path(tmp)
            out[label] = {
                "journal_begin": bench_journal(where, args.n),
                "state_write_0wp": bench_state(where, args.n, 0),
                "state_write_255wp": bench_state(where, max(10, args.n // 10), 255),
            }
    print(f"{'':8} {'what':20} {'median us':>10} {'p99 us':>10} {'max us':>10}")
    for label, rows in out.items():
        for what, r in rows.items():
            print(f"{label:8} {what:20} {r['median_us']:10} {r['p99_us']:10} {r['max_us']:10}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
