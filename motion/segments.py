"""Step segments: a run of steps as (first, interval, count, add), integer ticks.

Klipper's ``queue_step`` idea (not its code): the planner sends, per motor, runs of steps
whose times follow ``t[0] = first``, ``t[k+1] = t[k] + interval[k]``, ``interval[0] =
interval``, ``interval[k+1] = interval[k] + add``. The executor then needs one integer
addition per step and no square root. :func:`compress` finds the longest runs whose every
step is within ``max_error`` ticks of its exact time.

Pure functions; no I/O, no clock. Used by the planner (the daemon's process).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple


class StepSegment(NamedTuple):
    """``count`` steps in ``direction`` (+1/-1) of plan generation ``gen``.

    ``last``: the final segment of a finite plan (the executor reports DONE after it).
    ``watch``: the executor stops at the end stop ahead (off for stall homing).
    """

    first: int
    interval: int
    count: int  # type: ignore[assignment]  # shadows tuple.count: a field name of the design
    add: int
    direction: int
    gen: int
    last: bool = False
    watch: bool = True

    def times(self) -> list[int]:
        out = []
        t, iv = self.first, self.interval
        for _ in range(self.count):
            out.append(t)
            t += iv
            iv += self.add
        return out


def _fit(ts: Sequence[int], i: int, n: int) -> tuple[int, int]:
    """Interval and add through ts[i], ts[i + m] and ts[i + n - 1] (m the middle)."""
    t0 = ts[i]
    if n == 2:
        return ts[i + 1] - t0, 0
    k2 = n - 1
    k1 = k2 // 2
    d1, d2 = ts[i + k1] - t0, ts[i + k2] - t0
    # d = k*I + A*k*(k-1)/2 at k1 and k2
    a1, b1 = k1, k1 * (k1 - 1) / 2
    a2, b2 = k2, k2 * (k2 - 1) / 2
    det = a1 * b2 - a2 * b1
    if det == 0:
        return round(d2 / k2), 0
    add = round((a1 * d2 - a2 * d1) / det)
    interval = round((d2 - add * b2) / a2)
    return interval, add


def _fits(ts: Sequence[int], i: int, n: int, interval: int, add: int, err: int) -> bool:
    t, iv = ts[i], interval
    for k in range(i + 1, i + n):
        t += iv
        iv += add
        if abs(t - ts[k]) > err or iv <= 0:
            return False
    return True


def compress(
    ts: Sequence[int],
    direction: int,
    gen: int,
    max_error: int,
    last: bool = False,
    watch: bool = True,
) -> list[StepSegment]:
    """Cut step times ``ts`` (increasing ticks, one direction) into segments.

    Every reproduced step time is within ``max_error`` ticks of ``ts``; the first step of
    each segment is exact. ``last`` marks the final segment.
    """
    out: list[StepSegment] = []
    i, total = 0, len(ts)
    while i < total:
        left = total - i
        if left == 1:
            out.append(StepSegment(ts[i], 0, 1, 0, direction, gen, False, watch))
            i += 1
            continue
        good = 2
        best = (ts[i + 1] - ts[i], 0)
        n = 4
        bad = 0
        # grow by doubling, then bisect between the last good and the first bad count
        while True:
            n = min(n, left)
            iv, add = _fit(ts, i, n)
            if _fits(ts, i, n, iv, add, max_error):
                good, best = n, (iv, add)
                if n == left:
                    break
                n *= 2
            else:
                bad = n
                break
        while bad and bad - good > 1:
            mid = (good + bad) // 2
            iv, add = _fit(ts, i, mid)
            if _fits(ts, i, mid, iv, add, max_error):
                good, best = mid, (iv, add)
            else:
                bad = mid
        out.append(StepSegment(ts[i], best[0], good, best[1], direction, gen, False, watch))
        i += good
    if out and last:
        out[-1] = out[-1]._replace(last=True)
    return out
