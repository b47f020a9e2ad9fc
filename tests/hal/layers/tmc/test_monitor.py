"""The driver monitor thread (monitor.py): a poll that raises is a latched fault of its
driver, never a dead thread. Waits on a deadline."""

from __future__ import annotations

import time

from motorctl.hal.layers.tmc.monitor import DriverMonitor
from motorctl.hal.layers.tmc.settings import TmcSettings
from tests.support.spi_bench import SpiBench


def test_a_monitor_thread_survives_a_failing_poll(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130")
    spi_bench.chip("tmc2130", cs=1)
    good = spi_bench.driver(TmcSettings(poll_ms=1.0))
    bad = spi_bench.driver(TmcSettings(poll_ms=1.0), cs=1)
    good.start()
    bad.start()

    def broken() -> None:
        raise RuntimeError("bug")

    bad.poll = broken  # type: ignore[assignment,method-assign]
    monitor = DriverMonitor([good, bad], time.monotonic)
    monitor.start()
    deadline = time.monotonic() + 10.0
    try:
        while good.polls < 5:
            assert time.monotonic() < deadline, "the monitor did not poll 5 times within 10 s"
            time.sleep(0.005)
        status = bad.status()
        assert status.fault is not None and "internal error in the driver monitor" in status.fault
    finally:
        monitor.stop()
    assert good.polls >= 5
