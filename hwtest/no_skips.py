"""pytest plugin of the hardware tier: inside its guests a skip is a failure.

hwtest/run loads it (`-p hwtest.no_skips`) for the tests it runs in the QEMU guests. Outside
them the hardware tests skip themselves (no gpio-sim chip: `gsim.available()`), which is
right on a developer's machine; inside, a skip can only mean the guest lacks what the tier
exists to test (gpio-sim failed to load, a module is missing), and a run of "0 passed, 32
skipped" must not pass. Every skip, whether from a skip mark at set-up, `pytest.skip()` in a
test or a module skipped at collection (`importorskip`), becomes a failure naming its reason;
a run that collects no test at all already fails (pytest's exit status 5). Expected failures
(xfail) are left alone. Hooks run in pytest's main thread.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import pytest

PREFIX = "skipped in the hardware tier, where every test must run"


def _reason(longrepr: Any) -> str:
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2]).removeprefix("Skipped: ")
    return str(longrepr)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, Any, None]:
    outcome = yield
    report: pytest.TestReport = outcome.get_result()
    if report.skipped and not hasattr(report, "wasxfail"):
        report.outcome = "failed"
        report.longrepr = f"{PREFIX}: {_reason(report.longrepr)}"


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Generator[None, Any, None]:
    outcome = yield
    report: pytest.CollectReport = outcome.get_result()
    if report.skipped:
        report.outcome = "failed"
        report.longrepr = f"{PREFIX}: {collector.nodeid}: {_reason(report.longrepr)}"
