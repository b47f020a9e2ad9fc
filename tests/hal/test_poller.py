"""The HAL's driver poller (poller.py): what is registered is polled at its period, on a
virtual clock by whoever drives it and on a real one by its thread; faults and stalls (and
only they) are pushed to the consumer at every poll while they last; a poll that raises
faults its drivers and never stops the poller; a TMC driver is polled through its own
refresh. The thread's tests wait on deadlines."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence

import pytest

from motorctl.hal.interfaces import (
    DriverStatus,
    Edge,
    EdgeInputs,
    MonotonicClock,
    StepperDriver,
    VirtualClock,
)
from motorctl.hal.poller import DEFAULT_PERIOD_S, SLACK_S, DriverPoller, DriversConfig, Reading
from motorctl.schema import table_of
from tests.support.spi_bench import S2130, SpiBench


class Chip(StepperDriver):
    """A driver whose status a test sets; counts its reads."""

    def __init__(self) -> None:
        self.now = DriverStatus()
        self.reads = 0

    def status(self) -> DriverStatus:
        return self.now

    def refresh(self) -> DriverStatus:
        self.reads += 1
        return self.now


class Sink:
    def __init__(self) -> None:
        self.pushes: list[list[Reading]] = []

    def __call__(self, readings: Sequence[Reading]) -> None:
        self.pushes.append(list(readings))


def test_the_default_period_is_the_declared_one() -> None:
    (key,) = table_of(DriversConfig).keys
    assert key.default / 1000.0 == DEFAULT_PERIOD_S
    assert DriverPoller(VirtualClock()).period_s == DEFAULT_PERIOD_S


def test_each_entry_is_polled_at_its_period_and_only_news_is_pushed() -> None:
    clock = VirtualClock(0.0)
    poller = DriverPoller(clock, period_s=0.01)
    a, b, c = Chip(), Chip(), Chip()
    sink = Sink()
    poller.connect(sink)
    poller.watch(a, "a")
    poller.add("chain b+c", lambda: ((b, b.refresh()), (c, c.refresh())), (b, c), 0.025)
    assert poller.is_due(0.0)  # a new entry is polled at the first pass
    assert poller.poll_due(0.0) == pytest.approx(0.01)
    assert (a.reads, b.reads, c.reads) == (1, 1, 1)
    assert sink.pushes == []  # healthy: nothing to act on
    for t in (0.005, 0.01, 0.02, 0.025, 0.03):
        if poller.is_due(t):
            poller.poll_due(t)
    assert (a.reads, b.reads) == (4, 2)  # a at 0, 10, 20, 30 ms; the chain at 0 and 25 ms
    c.now = DriverStatus(fault="over-temperature")
    b.now = DriverStatus(stall=True)
    assert poller.next_due() == pytest.approx(0.04)
    poller.poll_due(0.05)
    assert sink.pushes == [[(b, b.now), (c, c.now)]]  # one push per pass, faults and stalls
    poller.poll_due(0.075)
    assert len(sink.pushes) == 2  # pushed again while it lasts: a level, not an edge
    c.now = b.now = DriverStatus()
    poller.poll_due(0.1)
    assert len(sink.pushes) == 2


def test_a_due_time_within_the_slack_is_due() -> None:
    """The engine's virtual clock stops on whole nanoseconds: a due time a rounding above
    it must still be polled, or run_until would stop at it for ever."""
    poller = DriverPoller(VirtualClock(0.0), period_s=0.003)
    chip = Chip()
    poller.watch(chip, "x")
    poller.poll_due(0.1)
    due = poller.next_due()
    assert poller.is_due(due - SLACK_S / 2)
    poller.poll_due(due - SLACK_S / 2)
    assert chip.reads == 2
    assert not poller.is_due(poller.next_due() - 2 * SLACK_S)


def test_removing_and_forgetting_stop_the_polls() -> None:
    poller = DriverPoller(VirtualClock(0.0))
    a, b = Chip(), Chip()
    entry = poller.watch(a, "a")
    poller.watch(b, "b")
    poller.remove(entry)
    poller.forget(b)
    assert poller.next_due() == math.inf and not poller.is_due(1e9)
    with pytest.raises(ValueError, match="a poll period is > 0 s"):
        poller.watch(a, "a", period_s=0.0)


def test_a_poll_that_raises_faults_its_drivers_and_the_poller_goes_on() -> None:
    poller = DriverPoller(VirtualClock(0.0))
    sink = Sink()
    poller.connect(sink)
    good, b, c = Chip(), Chip(), Chip()

    def broken() -> Sequence[Reading]:
        raise RuntimeError("bug")

    poller.add("chain", broken, (b, c))
    poller.watch(good, "good")
    poller.poll_due(0.0)
    ((first, second),) = sink.pushes
    assert [d for d, _ in (first, second)] == [b, c]
    fault = first[1].fault
    assert fault == "internal error in the driver poller (chain): RuntimeError('bug')"
    assert good.reads == 1 and poller.failures == 1 and poller.entries[0].failures == 1


def test_the_thread_polls_until_stopped_and_survives_a_failing_poll() -> None:
    poller = DriverPoller(MonotonicClock(), period_s=0.001)
    good = Chip()
    got = threading.Event()
    faults: list[str | None] = []

    def sink(readings: Sequence[Reading]) -> None:
        faults.extend(st.fault for _, st in readings)
        got.set()

    def broken() -> Sequence[Reading]:
        raise RuntimeError("bug")

    poller.connect(sink)
    poller.add("bad", broken, (Chip(),))
    poller.watch(good, "good")
    poller.start()
    try:
        assert good.reads >= 1  # read once before start returned
        assert poller.running and poller.alive
        assert got.wait(10.0), "no push within 10 s"
        deadline = time.monotonic() + 10.0
        while good.reads < 5:
            assert time.monotonic() < deadline, "the poller did not poll 5 times within 10 s"
            time.sleep(0.002)
    finally:
        poller.stop()
    assert not poller.running and poller.alive  # stopped: no thread is needed
    reads = good.reads
    time.sleep(0.01)
    assert good.reads == reads  # stopped means stopped
    assert faults and all(f is not None and "internal error" in f for f in faults)
    poller.stop()  # again: nothing to do


def test_no_thread_without_work_nor_on_a_virtual_clock() -> None:
    idle = DriverPoller(MonotonicClock())
    idle.start()
    assert not idle.running  # nothing registered
    virtual = DriverPoller(VirtualClock())
    virtual.watch(Chip(), "x")
    with pytest.raises(ValueError, match="real clock"):
        virtual.start()


def test_a_tmc_driver_is_read_through_its_refresh(spi_bench: SpiBench) -> None:
    """The poller reads the chip (DRV_STATUS over SPI) and hands its fault on once; the
    driver's transient fault is then forgotten, as when the engine read it itself."""
    model = spi_bench.chip("tmc2130")
    drv = spi_bench.driver(S2130)
    drv.start()
    poller = DriverPoller(spi_bench.clock, period_s=0.01)
    sink = Sink()
    poller.connect(sink)
    poller.watch(drv, "m0")
    model.power_cycle()  # a reset while running: a transient fault, reconfigured
    poller.poll_due(spi_bench.clock.now())
    assert drv.polls == 1
    ((reading,),) = sink.pushes
    assert reading[0] is drv and "reset and lost its configuration" in str(reading[1].fault)
    poller.poll_due(spi_bench.clock.now() + 0.01)
    assert drv.polls == 2 and len(sink.pushes) == 1  # reported once, healthy again


def test_before_is_called_once_before_each_pass_that_reads() -> None:
    """The consumer's ``before`` runs on the polling thread before any chip of a pass is read
    (the engine notes its motors' step counters there), and not for a pass with nothing due."""
    clock = VirtualClock(0.0)
    poller = DriverPoller(clock, period_s=0.01)
    chip = Chip()
    order: list[str] = []

    def read() -> Sequence[Reading]:
        order.append("read")
        return ((chip, chip.refresh()),)

    poller.add("chip", read, (chip,))
    poller.connect(Sink(), lambda: order.append("before"))
    poller.poll_due(0.0)
    poller.poll_due(0.005)  # nothing due
    poller.poll_due(0.01)
    assert order == ["before", "read", "before", "read"]


class Line(EdgeInputs):
    """An alert line whose edges a test hands over (stamped as the test says); counts how
    often the poller looks at it."""

    def __init__(self) -> None:
        super().__init__(["FLAG"])
        self.pending: list[Edge] = []
        self.reads = 0

    def read_edges(self) -> list[Edge]:
        self.reads += 1
        out, self.pending = self.pending, []
        return out

    def level(self, line: int) -> bool:
        return False


def test_an_alert_edge_is_polled_by_the_pass_that_reads_it() -> None:
    """FLAG falls: the pass that reads the edge reads the chip, even when the edge is stamped
    after the ``now`` the pass was given (a real clock is read before the lines are: the
    mock's lines stamp an edge when it is read, a kernel's edge may come in between), and the
    lines are read once per pass, not once for each look at what is due."""
    clock = VirtualClock(0.0)
    poller = DriverPoller(clock, period_s=0.02)
    chip = Chip()
    entry = poller.watch(chip, "chain")
    line = Line()
    poller.alert(entry, line, 0)
    poller.connect(Sink())
    poller.poll_due(0.0)
    assert chip.reads == 1 and line.reads == 1
    chip.now = DriverStatus(fault="OCD")
    line.pending = [Edge(0, True, 0.0051)]  # the fault, stamped just after the pass's now
    assert poller.poll_due(0.005) == pytest.approx(0.025)
    assert chip.reads == 2 and entry.alerts == 1  # read at once, not at the next pass
    assert line.reads == 2
