"""Lateness of step edges: a fixed-bin histogram, cheap enough for the step path.

The counters live in one flat sequence of ints (a list, or an int64 view of shared memory
when the step core runs in a process of its own): [count, late, max_ns, sum_ns, bins...,
blocks...]
(a block cell counts the edges of BLOCK consecutive bins). The step core is the only writer;
readers (status, benchmarks) read it without a lock and may see a histogram a few steps
behind or ahead of its counters, never a torn value.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, Final, Protocol


class Cells(Protocol):
    """Int cells: a list, or an int64 ``memoryview`` of shared memory."""

    def __getitem__(self, i: int, /) -> int: ...

    def __setitem__(self, i: int, v: int, /) -> None: ...

    def __len__(self) -> int: ...


BINS = 20_000  # 1 us bins up to 20 ms; later edges go to the overflow bin
#: Bins are also counted by blocks of BLOCK: a reader visits only the blocks that hold
#: something, so a snapshot costs the number of busy bins, not BINS.
BLOCK_SHIFT = 6
BLOCK = 1 << BLOCK_SHIFT
BLOCKS = (BINS + 1 + BLOCK - 1) // BLOCK
_COUNT, _LATE, _MAX, _SUM = 0, 1, 2, 3  # _SUM: lateness summed (ns; early edges as 0)
_BINS = 4
_BLOCKS = _BINS + BINS + 1
CELLS = _BLOCKS + BLOCKS


#: a step edge later than this counts as late ([step_thread] late_threshold_us declares it
#: with this value)
LATE_THRESHOLD_S: Final = 100e-6


class LatencyStats:
    def __init__(self, threshold_s: float = LATE_THRESHOLD_S, cells: Cells | None = None) -> None:
        if not threshold_s >= 0:
            raise ValueError(f"a lateness threshold of {threshold_s} s: it cannot be negative")
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
    def sum_s(self) -> float:
        """All edges' lateness added up (early ones as 0): a summary's ``_sum``."""
        return self._c[_SUM] / 1e9

    def _span(self, start: int, stop: int) -> list[int]:
        """Cells ``start:stop`` as a list, in one C-level copy (a list or shared memory)."""
        c = self._c
        if isinstance(c, memoryview):
            return c[start:stop].tolist()
        if isinstance(c, list):
            return c[start:stop]
        return [int(c[i]) for i in range(start, stop)]

    @property
    def bins(self) -> list[int]:
        """Every bin (the last: beyond BINS us); a full copy, for tests and tools."""
        return self._span(_BINS, _BINS + BINS + 1)

    def record(self, lateness_s: float) -> None:
        self.record_ns(round(lateness_s * 1e9))

    def record_ns(self, ns: int) -> None:
        """One edge (or command) ``ns`` late; early or on time (``ns`` <= 0) counts in the
        first bin and adds nothing to the sum. The maximum starts at 0 and the threshold is
        not negative, so neither can move for an edge that was not late at all: they are
        looked at only for one that was (the link records every command here)."""
        c = self._c
        c[_COUNT] += 1
        if ns > 0:
            c[_SUM] += ns
            if ns > c[_MAX]:
                c[_MAX] = ns
            if ns > self._threshold_ns:
                c[_LATE] += 1
            us = ns // 1000
            if us > BINS:
                us = BINS
            c[_BINS + us] += 1
            c[_BLOCKS + (us >> BLOCK_SHIFT)] += 1
        else:
            c[_BINS] += 1
            c[_BLOCKS] += 1

    def histogram(self) -> dict[int, int]:
        """Non-empty bins, in order: lateness in whole microseconds -> count (the last bin,
        BINS: beyond). Visits only the blocks that hold something: its cost is the number
        of busy blocks, not BINS, so a status read stays cheap."""
        out: dict[int, int] = {}
        blocks = self._span(_BLOCKS, _BLOCKS + BLOCKS)
        for b in itertools.compress(range(BLOCKS), blocks):
            first = b << BLOCK_SHIFT
            seg = self._span(_BINS + first, _BINS + min(first + BLOCK, BINS + 1))
            out.update(
                zip(
                    itertools.compress(range(first, first + len(seg)), seg),
                    filter(None, seg),
                    strict=True,
                )
            )
        return out

    def percentile_us(self, q: float) -> float:
        """The q-th percentile (0..100) in microseconds, at 1 us resolution."""
        return self._percentiles((q,))[0]

    def _percentiles(self, qs: Sequence[float]) -> list[float]:
        """Nearest rank of each of ``qs`` (ascending): walks the block counts only as far
        as the last rank's block (the busy blocks at the start, as a rule), then looks in
        each rank's block at its own bins: the cost is bounded, however spread the
        histogram. A bin read a step ahead of or behind its block's count moves the answer
        by at most that step, never outside the block."""
        blocks = self._span(_BLOCKS, _BLOCKS + BLOCKS)
        count = sum(blocks)
        if count == 0:
            return [0.0] * len(qs)
        out = []
        b = seen = 0  # the block looked at, and the edges in the blocks before it
        for q in qs:
            exact = q / 100.0 * count
            rank = max(1, math.ceil(exact - 1e-12 * exact))  # 99.9% of 1000 is 999, not 1000
            while seen + blocks[b] < rank:
                seen += blocks[b]
                b += 1
            first = b << BLOCK_SHIFT
            seg = self._span(_BINS + first, _BINS + min(first + BLOCK, BINS + 1))
            us, got = first, seen
            for j, n in enumerate(seg):
                if n:
                    us = first + j
                    got += n
                    if got >= rank:
                        break
            out.append(float(us) if us < BINS else self.max_s * 1e6)
        return out

    def summary(self) -> dict[str, Any]:
        """Count, p50/p99/p99.9, max, sum and late steps: a bounded cost (the blocks and three of
        them), whatever the spread, so the status and the watchdog can ask often."""
        p50, p99, p999 = self._percentiles((50, 99, 99.9))
        return {
            "steps": self.count,
            "p50_us": p50,
            "p99_us": p99,
            "p999_us": p999,
            "max_us": round(self.max_s * 1e6, 1),
            "sum_us": round(self.sum_s * 1e6, 1),
            "late": self.late,
            "late_threshold_us": self.threshold_s * 1e6,
        }
