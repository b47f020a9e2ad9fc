"""Lateness of step edges: a fixed-bin histogram, cheap enough for the step thread."""

from __future__ import annotations

import math
from typing import Any

_BINS = 20_000  # 1 us bins up to 20 ms; later edges go to the overflow bin


class LatencyStats:
    def __init__(self, threshold_s: float = 100e-6) -> None:
        self.threshold_s = threshold_s
        self.reset()

    def reset(self) -> None:
        self.bins = [0] * (_BINS + 1)
        self.count = 0
        self.late = 0
        self.max_s = 0.0

    def record(self, lateness_s: float) -> None:
        self.count += 1
        if lateness_s > self.max_s:
            self.max_s = lateness_s
        if lateness_s > self.threshold_s:
            self.late += 1
        # The epsilon keeps whole microseconds whole (15e-6 * 1e6 is 14.999999999999998).
        us = int(lateness_s * 1e6 + 1e-6)
        self.bins[us if 0 <= us < _BINS else (0 if us < 0 else _BINS)] += 1

    def percentile_us(self, q: float) -> float:
        """The q-th percentile (0..100) in microseconds, at 1 us resolution."""
        if self.count == 0:
            return 0.0
        exact = q / 100.0 * self.count
        rank = max(1, math.ceil(exact - 1e-12 * exact))  # 99.9% of 1000 is 999, not 1000
        seen = 0
        for us, n in enumerate(self.bins):
            seen += n
            if seen >= rank:
                return float(us) if us < _BINS else self.max_s * 1e6
        return self.max_s * 1e6

    def histogram(self) -> dict[int, int]:
        """Non-empty bins: lateness in whole microseconds -> count (the last bin: beyond)."""
        return {us: n for us, n in enumerate(self.bins) if n}

    def summary(self) -> dict[str, Any]:
        return {
            "steps": self.count,
            "p50_us": self.percentile_us(50),
            "p99_us": self.percentile_us(99),
            "p999_us": self.percentile_us(99.9),
            "max_us": round(self.max_s * 1e6, 1),
            "late": self.late,
            "late_threshold_us": self.threshold_s * 1e6,
        }
