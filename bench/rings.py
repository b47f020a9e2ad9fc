"""The per-record cost of the shared-memory rings of the process step executor.

One put plus one get of a segment record, a stop record and an event record (with its
text), in one process on a ring in a real POSIX shared-memory block, timed with timeit
on this thread's CPU time (so a busy machine's preemptions do not count; best of
``--repeat`` runs of ``--number`` records). Prints ns per record and writes the
figures with ``--json FILE`` (flat keys ``seg_put_get_ns``, ``stop_put_get_ns``,
``event_put_get_ns``, ``seg_get_ns``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motorctl.hal.shm import SharedBlock  # noqa: E402
from motorctl.motion.executors.process.rings import (  # noqa: E402
    EVENT_RECORD,
    EVENT_RING,
    SEG_RECORD,
    SEG_RING,
    STOP_RECORD,
    STOP_RING,
    Ring,
    ring_size,
)


def measure(number: int, repeat: int) -> dict[str, float]:
    rings = {
        "seg": (SEG_RECORD, SEG_RING),
        "stop": (STOP_RECORD, STOP_RING),
        "event": (EVENT_RECORD, EVENT_RING),
    }
    size = sum(ring_size(rec, cap) for rec, cap in rings.values())
    shm = SharedBlock.create(size, "motorctl-bench-rings")  # the executor's kind of block
    out: dict[str, float] = {}
    try:
        off = 0
        made: dict[str, Ring] = {}
        for name, (rec, cap) in rings.items():
            made[name] = Ring(shm.buf, off, rec, cap)
            off += ring_size(rec, cap)
        seg, stop, event = made["seg"], made["stop"], made["event"]
        text = b"step timing lost (step 2417 us late)"

        def seg_round() -> None:
            seg.put(1_000_000_123, 250_000, 4000, -3, 1, 7, 1)
            seg.get()

        def stop_round() -> None:
            stop.put(2, 9, -1)  # motor, gen, cut (-1: a hard stop)
            stop.get()

        def event_round() -> None:
            event.put(3, 1, 7, 123456, 1_000_000_000, 1, 4000.0, text)
            event.get()

        for name, fn in (("seg", seg_round), ("stop", stop_round), ("event", event_round)):
            best = min(timeit.Timer(fn, timer=time.thread_time).repeat(repeat, number))
            out[f"{name}_put_get_ns"] = round(best / number * 1e9, 1)
        # get alone (the step core's side): fill, then drain, SEG_RING records at a time
        gets: list[float] = []
        for _ in range(repeat):
            for _ in range(SEG_RING):
                seg.put(1_000_000_123, 250_000, 4000, -3, 1, 7, 1)
            gets.append(timeit.Timer(seg.get, timer=time.thread_time).timeit(SEG_RING))
        out["seg_get_ns"] = round(min(gets) / SEG_RING * 1e9, 1)
        for ring in made.values():
            ring.release()
    finally:
        shm.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--number", type=int, default=100_000, help="records per timed run")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs; the best counts")
    ap.add_argument("--json", type=Path, help="write the figures to this file")
    args = ap.parse_args()
    figures = measure(args.number, args.repeat)
    for key, value in figures.items():
        print(f"{key:20} {value:8.1f} ns")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")


if __name__ == "__main__":
    main()
