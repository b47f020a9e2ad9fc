"""The benchmarks (each runs as a script: `python bench/NAME.py`) and what they share."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

RT_RUNTIME = Path("/proc/sys/kernel/sched_rt_runtime_us")


def rt_runtime() -> str | None:
    """kernel.sched_rt_runtime_us now (None where it cannot be read)."""
    return RT_RUNTIME.read_text().strip() if RT_RUNTIME.exists() else None


@contextlib.contextmanager
def rt_throttling_off(enabled: bool = True) -> Iterator[str | None]:
    """kernel.sched_rt_runtime_us = -1 for the block when ``enabled`` (and root), restored
    after, whatever happens: a busy-waiting executor is not parked 50 ms a second
    (docs/timing.md). Yields the value before."""
    before = rt_runtime()
    change = enabled and before is not None and os.geteuid() == 0
    if change:
        RT_RUNTIME.write_text("-1\n")
    try:
        yield before
    finally:
        if change:
            RT_RUNTIME.write_text(f"{before}\n")
