"""The lateness histogram (motion/latency.py): percentiles by nearest rank, a bin per
microsecond, early edges on time, overflow as the maximum, the block counts the status reads
agreeing with a scan of every bin, in a plain list or shared cells."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.motion.latency import LatencyStats


def test_latency_percentiles_on_known_data() -> None:
    stats = LatencyStats(threshold_s=50e-6)
    for us in range(1, 101):
        stats.record(us * 1e-6)
    assert stats.count == 100
    assert stats.percentile_us(50) == 50.0
    assert stats.percentile_us(90) == 90.0
    assert stats.percentile_us(99) == 99.0
    assert stats.percentile_us(100) == 100.0
    assert stats.percentile_us(0) == 1.0
    assert stats.late == 50
    assert stats.max_s == pytest.approx(100e-6)


def test_latency_every_microsecond_lands_in_its_bin() -> None:
    stats = LatencyStats()
    for us in range(20_000):
        stats.record(us * 1e-6)
    assert stats.bins == [1] * 20_000 + [0]
    stats.record(20_000e-6)
    assert stats.bins[-1] == 1


def test_latency_nearest_rank() -> None:
    stats = LatencyStats()
    for us in range(1, 1001):
        stats.record(us * 1e-6)
    assert stats.percentile_us(99.9) == 999.0
    assert stats.percentile_us(99) == 990.0
    s = stats.summary()
    assert (s["steps"], s["p50_us"], s["p99_us"], s["p999_us"]) == (1000, 500.0, 990.0, 999.0)
    assert s["max_us"] == 1000.0


def test_latency_overflow_early_and_reset() -> None:
    stats = LatencyStats(threshold_s=100e-6)
    assert stats.percentile_us(50) == 0.0
    stats.record(-5e-6)  # early edges count as on time
    stats.record(0.0)
    stats.record(0.035)  # beyond the histogram: reported as the maximum
    assert stats.percentile_us(50) == 0.0
    assert stats.percentile_us(100) == pytest.approx(35_000.0)
    assert stats.late == 1
    stats.reset()
    assert stats.count == 0 and stats.late == 0 and stats.percentile_us(99) == 0.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.one_of(st.integers(-50, 3_000), st.integers(0, 25_000)), min_size=1, max_size=400),
    st.booleans(),
)
def test_latency_blocks_agree_with_a_full_scan(lateness_us: list[int], shared: bool) -> None:
    """The status reads the histogram and percentiles through the block counts (a cost of
    the busy blocks, not 20,001 bins): the same answers as a scan of every bin."""
    import array

    from motorctl.motion.latency import BINS, CELLS

    cells = memoryview(array.array("q", bytes(8 * CELLS))) if shared else None
    stats = LatencyStats(cells=cells)
    for us in lateness_us:
        stats.record_ns(us * 1000 + 500)
    bins = stats.bins
    assert stats.histogram() == {us: n for us, n in enumerate(bins) if n}
    cum = list(itertools.accumulate(bins))
    for q in (0, 1, 50, 99, 99.9, 100):
        rank = max(1, math.ceil(q / 100 * len(lateness_us) - 1e-12 * q / 100 * len(lateness_us)))
        us = next(i for i, c in enumerate(cum) if c >= rank)
        want = float(us) if us < BINS else stats.max_s * 1e6
        assert stats.percentile_us(q) == want, q
    summary = stats.summary()  # its three percentiles in one walk: the same answers
    assert [summary["p50_us"], summary["p99_us"], summary["p999_us"]] == [
        stats.percentile_us(q) for q in (50, 99, 99.9)
    ]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.integers(-(10**7), 10**5), st.integers(10**5, 3 * 10**10), st.sampled_from([0, 1])
        ),
        max_size=60,
    ),
    st.sampled_from([0.0, 1e-9, 108e-6, 1.0]),
)
def test_latency_every_cell_as_each_edge_says(lateness_ns: list[int], threshold_s: float) -> None:
    """Every cell after any lateness in ns, early and exact ones included, as the rule says it
    cell by cell: counted; the maximum and the late count moved by what exceeds them; the sum
    of what was late; its microsecond's bin (early ones in the first, beyond BINS in the
    last) and that bin's block."""
    from motorctl.motion.latency import _BINS, _BLOCKS, BINS, BLOCK_SHIFT, CELLS

    stats = LatencyStats(threshold_s)
    want = [0] * CELLS
    for ns in lateness_ns:
        stats.record_ns(ns)
        want[0] += 1
        want[1] += ns > int(threshold_s * 1e9)
        want[2] = max(want[2], ns)
        want[3] += max(ns, 0)
        us = min(max(ns, 0) // 1000, BINS)
        want[_BINS + us] += 1
        want[_BLOCKS + (us >> BLOCK_SHIFT)] += 1
    assert stats._c == want


def test_a_negative_lateness_threshold_is_refused() -> None:
    with pytest.raises(ValueError, match="cannot be negative"):
        LatencyStats(-1e-6)
