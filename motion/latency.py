"""Lateness of step edges: a fixed-bin histogram, cheap enough for the step path.

The counters live in one flat sequence of ints (a list, or an int64 view of shared memory
when the step core runs in a process of its own): [count, late, max_ns, bins...]. The step
core is the only writer; readers (status, benchmarks) read it without a lock and may see a
histogram a few steps behind its counters, never a torn value.
"""

from __future__ import annotations

import bisect
import itertools
import math
from typing import Any, Protocol


class Cells(Protocol):
    """Int cells: a list, or an int64 ``memoryview`` of shared memory."""

    def __getitem__(self, i: int, /) -> int: ...

    def __setitem__(self, i: int, v: int, /) -> None: ...

    def __len__(self) -> int: ...


BINS = 20_000  # 1 us bins up to 20 ms; later edges go to the overflow bin
CELLS = 3 + BINS + 1
_COUNT, _LATE, _MAX = 0, 1, 2


class LatencyStats:
    def __init__(
        self, threshold_s: float = 100e-6, cells: Cells | None = None
    ) -> None:
        self.threshold_s = threshold_s
        self._threshold_ns = int(threshold_s * 1e9)
        self._c: Cells = cells if cells is not None else [0] * CELLS
        if len(self._c) < CELLS:
            raise ValueError(f"latency cells need {CELLS} slots")

    def reset(self) -> None:
        for i in range(CELLS):
            self._c[i] = 0

    @property
    def count(self) -> int:
        return int(self._c[_COUNT])

    @property
    def late(self) -> int:
        return int(self._c[_LATE])

    @property
    def max_s(self) -> float:
        return self._c[_MAX] / 1e9

    @property
    def bins(self) -> list[int]:
        c = self._c
        if isinstance(c, memoryview):
            return c[3:CELLS].tolist()  # one C-level copy of shared memory
        return [int(c[i]) for i in range(3, CELLS)]

    def record(self, lateness_s: float) -> None:
        self.record_ns(round(lateness_s * 1e9))

    def record_ns(self, ns: int) -> None:
        c = self._c
        c[_COUNT] += 1
        if ns > c[_MAX]:
            c[_MAX] = ns
        if ns > self._threshold_ns:
            c[_LATE] += 1
        us = ns // 1000 if ns >= 0 else 0
        c[3 + (us if us < BINS else BINS)] += 1

    def percentile_us(self, q: float, bins: list[int] | None = None) -> float:
        """The q-th percentile (0..100) in microseconds, at 1 us resolution."""
        cum = list(itertools.accumulate(self.bins if bins is None else bins))
        return self._percentile(q, cum)

    def _percentile(self, q: float, cum: list[int]) -> float:
        count = cum[-1] if cum else 0
        if count == 0:
            return 0.0
        exact = q / 100.0 * count
        rank = max(1, math.ceil(exact - 1e-12 * exact))  # 99.9% of 1000 is 999, not 1000
        us = bisect.bisect_left(cum, rank)
        return float(us) if us < BINS else self.max_s * 1e6

    def histogram(self) -> dict[int, int]:
        """Non-empty bins: lateness in whole microseconds -> count (the last bin: beyond)."""
        bins = self.bins
        return {us: bins[us] for us in itertools.compress(range(len(bins)), bins)}

    def summary(self) -> dict[str, Any]:
        cum = list(itertools.accumulate(self.bins))  # one snapshot for all three
        return {
            "steps": self.count,
            "p50_us": self._percentile(50, cum),
            "p99_us": self._percentile(99, cum),
            "p999_us": self._percentile(99.9, cum),
            "max_us": round(self.max_s * 1e6, 1),
            "late": self.late,
            "late_threshold_us": self.threshold_s * 1e6,
        }
