"""The deadline wait: every test that waits for another thread or process waits here.

Time in tests is a virtual clock wherever it can be; where a real thread or process must
get somewhere, the test polls a condition until a generous deadline (a loaded 2-core
machine) and fails naming what it waited for, never a bare ``sleep`` and hope.
"""

from __future__ import annotations

import time
from collections.abc import Callable

#: A deadline for conditions that take milliseconds (a loaded 2-core machine).
WAIT_S = 30.0


def until(
    what: str,
    cond: Callable[[], object],
    timeout: float = WAIT_S,
    *,
    detail: Callable[[], object] | None = None,
    every_s: float = 0.001,
) -> None:
    """Poll ``cond`` every ``every_s`` until it holds; after ``timeout`` seconds fail naming
    ``what`` (and ``detail()``, say the counters or faults that explain it)."""
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            extra = f"; {detail()}" if detail is not None else ""
            raise AssertionError(f"timed out after {timeout} s waiting for {what}{extra}")
        time.sleep(every_s)
