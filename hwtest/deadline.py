"""pytest plugin of the hardware tier: a test that hangs ends the run at once, with every stack.

hwtest/run loads it (`-p hwtest.deadline`) in its QEMU guests. The guest as a whole has a
budget (GSIM_TIMEOUT, 1200 s); a test stuck on something without a deadline of its own used to
spend all of it, and the host's `timeout` then killed the VM with no word of where it hung.
Here each test (set-up, call and tear-down) gets HWTEST_DEADLINE_S seconds (default 240: the
slowest test takes about 30 s under TCG on a loaded host); when they run out,
faulthandler prints "Timeout" and the traceback of every thread of pytest's process and ends
it (status 1); `pytest -v` has already printed the stuck test's name, the guest powers off
and the next binding's run goes on.
Hooks run in pytest's main thread.
"""

from __future__ import annotations

import faulthandler
import os
from collections.abc import Generator

import pytest

DEFAULT_S = 240.0


def deadline_s() -> float:
    text = os.environ.get("HWTEST_DEADLINE_S", "")
    try:
        value = float(text) if text else DEFAULT_S
    except ValueError:
        raise pytest.UsageError(f"HWTEST_DEADLINE_S={text!r}: not a number of seconds") from None
    if not value > 0:
        raise pytest.UsageError(f"HWTEST_DEADLINE_S={text!r}: must be more than 0")
    return value


_LIMIT = pytest.StashKey[float]()
_FD = pytest.StashKey[int]()


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_LIMIT] = deadline_s()
    # the console as it is now: while a test runs pytest points fd 2 at its capture file
    config.stash[_FD] = os.dup(2)


def pytest_unconfigure(config: pytest.Config) -> None:
    if _FD in config.stash:
        os.close(config.stash[_FD])


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Generator[None, object, None]:
    stash = item.config.stash
    faulthandler.dump_traceback_later(stash[_LIMIT], exit=True, file=stash[_FD])
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()
