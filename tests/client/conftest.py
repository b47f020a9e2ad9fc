"""The trace tests' two modules do not run side by side: tests/client/test_trace_e2e.py
records sessions and replays them, judging how long each WaitMoved was held against the
recording within tens of milliseconds (the test daemons run without real-time priority),
while tests/client/test_trace_files.py reads thousands of damaged files and starts tshark,
a core's worth of work for seconds: beside it, on a 2-core machine, the motions the first
times stretched by more than its tolerance. A lock file in build/ keeps them apart across
the xdist workers of one run (the first holds it shared, so its own tests still spread
over both workers; the second exclusively). ``--dist loadgroup`` would do it, but
pytest-xdist 3.8 groups by a node id pytest 9 no longer reads."""

from __future__ import annotations

import fcntl
import time
import warnings
from collections.abc import Iterator

import pytest

from tests.support import REPO

LOCK = REPO / "build" / "trace-tests.lock"
MODES = {"test_trace_e2e": fcntl.LOCK_SH, "test_trace_files": fcntl.LOCK_EX}
WAIT_S = 300.0  # then run anyway (a worker idle between two of its tests holds it)


@pytest.fixture(scope="module", autouse=True)
def apart_from_the_other_trace_module(request: pytest.FixtureRequest) -> Iterator[None]:
    mode = MODES.get(request.module.__name__.rsplit(".", 1)[-1])
    if mode is None:
        yield
        return
    LOCK.parent.mkdir(exist_ok=True)
    with open(LOCK, "a") as lock:  # build/ is the worktree's own: a plain file there
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                fcntl.flock(lock, mode | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    warnings.warn(
                        f"{LOCK} stayed locked for {WAIT_S:.0f} s: running anyway", stacklevel=2
                    )
                    break
                time.sleep(0.05)
        yield
