"""The HAL's driver poller: one thread reads every driver chip at one period and pushes what
needs acting on (a fault, a stall) to its consumer as soon as it is read.

What is polled, layers register (:meth:`DriverPoller.add`): a poll function that reads one
chip, or every chip of a daisy chain in one exchange, and returns each driver's status; the
drivers it reads (named when it fails); and a period (None: the poller's own, ``[drivers]
poll_ms``). :meth:`DriverPoller.watch` registers one driver's own
:meth:`~motorctl.hal.interfaces.StepperDriver.refresh`. The backends register theirs the
same way (the mock's simulated chips); a driver with nothing to read (a step/dir driver) is
not registered.

The consumer (the motion engine) connects once (:meth:`DriverPoller.connect`), with an
optional ``before`` called on the polling thread just before a pass reads anything (the
engine notes each motor's step counter there: a stall read before a motion's first step is
the last motion's, see ``Motor.on_driver_status``). After each pass, the readings with a
fault or a stall go to it in one call, on the poller's thread: it queues them and wakes its
own thread, which acts on them under its lock at once, and before it answers the host's next
command. A reading is pushed at every poll while its condition lasts (a level, as the chips
report it), so nothing is lost to a consumer that acts later.

An alert line (:meth:`DriverPoller.alert`: a chip's FLAG output read as edges,
``Hardware.open_alert_lines``) makes its poll due at once when it falls: the thread waits
on the lines' descriptors as well as on its period, so a fault the chip signals is read
within a pass's time rather than a period's; on a virtual clock the edges are taken
whenever the engine asks what is due (:meth:`DriverPoller.next_due`).

A real clock: :meth:`DriverPoller.start` runs the ``motorctl-drivers`` thread (its consumer
starts it, and stops it, bounded; the Hardware's close stops it too). A virtual clock: no
thread; the engine asks :meth:`DriverPoller.next_due` and calls
:meth:`DriverPoller.poll_due` in time order with everything else it runs
(``MotionEngine.run_until``), so tests poll deterministically.

Threads: the schedule and the counters belong to the thread that polls (the poller's, or
the engine's run on a virtual clock); registration happens at start-up, before it runs. A
poll function runs on that thread and may block on its bus; one that raises is logged and
its drivers reported faulted ("internal error in the driver poller"): the thread never dies.
"""

from __future__ import annotations

import logging
import math
import os
import select
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from motorctl.hal.interfaces import Clock, DriverStatus, EdgeInputs, HalError, StepperDriver
from motorctl.schema import number, section, table_of

log = logging.getLogger("motorctl.drivers")

#: a driver and its status as a poll read it
Reading = tuple[StepperDriver, DriverStatus]
PollFunction = Callable[[], Sequence[Reading]]
Sink = Callable[[Sequence[Reading]], None]

#: a poll due within this long counts as due now: a caller whose clock rounds (the engine's
#: virtual clock stops on whole nanoseconds) never finds it due and leaves it unpolled
SLACK_S = 1e-6


@section(
    "The HAL's driver poller: how often every driver chip's status is read.",
    notes="""\
One thread (`motorctl-drivers`) reads every driver chip that reports a status (a TMC
chip's DRV_STATUS; the mock's simulated drivers) every `poll_ms` and hands a fault or a
stall to the motion engine as soon as it has read it: the engine acts on it at once, so a
fault reaches the host's next command within about `poll_ms` (docs/timing.md, "Driver
faults"). A shorter period costs bus transfers and CPU time: a TMC chip's poll is 3 SPI
datagrams.""",
)
@dataclass(frozen=True)
class DriversConfig:
    """[drivers]: the driver poller."""

    poll_ms: float = number(
        20.0,
        1.0,
        10000.0,
        "How often every driver chip's status (faults, stall) is read; a fault reaches the "
        "host's next command within about this long.",
    )


def _declared_period_s() -> float:
    key = next(k for k in table_of(DriversConfig).keys if k.name == "poll_ms")
    return float(key.default) / 1000.0


#: the poller's period when the config says nothing (``[drivers] poll_ms``'s default)
DEFAULT_PERIOD_S = _declared_period_s()


@dataclass(eq=False)
class Polled:
    """One registered poll: a chip or a chain, its drivers, its period (None: the poller's)."""

    name: str
    poll: PollFunction
    drivers: tuple[StepperDriver, ...]
    period_s: float | None = None
    due: float = 0.0  # when it is polled next (registered: now, so the first pass polls it)
    polls: int = 0
    failures: int = 0
    alerts: int = 0  # the falling edges of its alert lines that made it due at once


@dataclass(eq=False)
class Alert:
    """An alert line: ``line`` of ``inputs`` falling makes ``entry`` due at once."""

    inputs: EdgeInputs
    line: int
    entry: Polled
    falls: int = 0  # its falling edges that made the poll due at once (the entry's alerts)


@dataclass(eq=False)
class DriverPoller:
    """The one driver poller of a machine (``Hardware.poller``); see the module's doc."""

    clock: Clock
    period_s: float = DEFAULT_PERIOD_S
    join_s: float = 2.0
    entries: list[Polled] = field(default_factory=list)
    rounds: int = 0
    failures: int = 0  # poll functions that raised
    alerts: list[Alert] = field(default_factory=list)
    _sink: Sink | None = field(default=None, init=False, repr=False)
    _before: Callable[[], None] | None = field(default=None, init=False, repr=False)
    _thread: threading.Thread | None = field(default=None, init=False, repr=False)
    _stopping: bool = field(default=False, init=False, repr=False)
    _kick: threading.Event = field(default_factory=threading.Event, init=False, repr=False)
    _wake: tuple[int, int] | None = field(default=None, init=False, repr=False)

    # -- registration (start-up) ---------------------------------------------------------
    def add(
        self,
        name: str,
        poll: PollFunction,
        drivers: Sequence[StepperDriver],
        period_s: float | None = None,
    ) -> Polled:
        """Poll ``poll`` (reading ``drivers``) every ``period_s`` (None: the poller's)."""
        if period_s is not None and not period_s > 0:
            raise ValueError(f"{name}: a poll period is > 0 s, not {period_s}")
        entry = Polled(name, poll, tuple(drivers), period_s, due=self.clock.now())
        self.entries.append(entry)
        return entry

    def watch(self, driver: StepperDriver, name: str, period_s: float | None = None) -> Polled:
        """Poll one driver's own ``refresh()`` (a chip read on its own)."""
        return self.add(name, lambda: ((driver, driver.refresh()),), (driver,), period_s)

    def alert(self, entry: Polled, inputs: EdgeInputs, line: int) -> Alert:
        """Poll ``entry`` as soon as ``line`` of ``inputs`` falls (its ``active`` edge); the
        thread waits on ``inputs.fileno()``, which a real clock needs."""
        if not self.clock.is_virtual and inputs.fileno() is None:
            raise ValueError(f"{entry.name}: an alert line needs a descriptor to wait on")
        found = Alert(inputs, line, entry)
        self.alerts.append(found)
        return found

    def _take_alerts(self, now: float) -> None:
        """The alert lines' edges since the last look (no bus transfer): a falling one
        makes its poll due at the edge's time, or ``now`` if the edge is stamped later (a
        real clock read before the edges were): the pass that takes an edge polls."""
        done: set[int] = set()
        for a in self.alerts:
            if id(a.inputs) in done:
                continue
            done.add(id(a.inputs))
            try:
                edges = a.inputs.read_edges()
            except HalError as exc:  # the poll at its period still reads the chips
                log.error("%s: its alert line could not be read: %s", a.entry.name, exc)
                continue
            for e in edges:
                for b in self.alerts:
                    if b.inputs is a.inputs and b.line == e.line and e.active:
                        b.entry.due = min(b.entry.due, e.t, now)
                        b.entry.alerts += 1
                        b.falls += 1

    def remove(self, entry: Polled) -> None:
        self.entries = [e for e in self.entries if e is not entry]

    def forget(self, driver: StepperDriver) -> None:
        """Stop polling what reads ``driver`` (a test that puts another in its place)."""
        self.entries = [e for e in self.entries if driver not in e.drivers]

    def connect(self, sink: Sink, before: Callable[[], None] | None = None) -> None:
        """Where readings with a fault or a stall go (the engine's queue); one consumer.
        ``before``: called just before each pass that reads something."""
        self._sink, self._before = sink, before

    # -- polling (the poller's thread, or the engine's on a virtual clock) ------------------
    def period_of(self, entry: Polled) -> float:
        return self.period_s if entry.period_s is None else entry.period_s

    def next_due(self) -> float:
        """When the next poll is due (``inf``: nothing to poll); an alert line that fell
        makes its poll due now."""
        if self.alerts:
            self._take_alerts(self.clock.now())
        return self._earliest()

    def _earliest(self) -> float:
        return min((e.due for e in self.entries), default=math.inf)

    def is_due(self, now: float) -> bool:
        """Whether a poll is due at ``now`` (within ``SLACK_S``)."""
        return self.next_due() <= now + SLACK_S

    def poll_due(self, now: float) -> float:
        """Poll every entry due at ``now``, push what needs acting on; the next due time.
        The alert lines are read once, first (an edge read later wakes the thread's wait on
        their descriptors, or is taken by the next :meth:`next_due`)."""
        news: list[Reading] = []
        if self.alerts:
            self._take_alerts(now)
        before = self._before
        if before is not None and self._earliest() <= now + SLACK_S:
            before()
        for e in self.entries:
            if e.due > now + SLACK_S:
                continue
            e.due = now + self.period_of(e)
            news += [r for r in self._poll(e) if r[1].fault is not None or r[1].stall]
        self.rounds += 1
        sink = self._sink
        if news and sink is not None:
            sink(news)
        return self._earliest()

    def _poll(self, e: Polled) -> Sequence[Reading]:
        e.polls += 1
        try:
            return e.poll()
        except Exception as exc:  # a bug must not kill the poller: its drivers fault
            log.exception("%s: driver poll failed", e.name)
            e.failures += 1
            self.failures += 1
            fault = DriverStatus(fault=f"internal error in the driver poller ({e.name}): {exc!r}")
            return [(d, fault) for d in e.drivers]

    # -- the thread (a real clock) ----------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None

    @property
    def alive(self) -> bool:
        """The thread runs, or none is needed (nothing to poll, not started)."""
        thread = self._thread
        return thread is None or thread.is_alive()

    def start(self) -> None:
        """Run the ``motorctl-drivers`` thread (nothing to poll: no thread). What is due
        (every chip, the first time) is polled first on the caller's thread, so the
        chips have been read once when this returns (before the daemon says READY)."""
        if self._thread is not None or not self.entries:
            return
        if self.clock.is_virtual:
            raise ValueError("the driver poller's thread runs on a real clock; tests use poll_due")
        self.poll_due(self.clock.now())
        self._stopping = False
        self._kick.clear()
        if self.alerts and self._wake is None:
            self._wake = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._thread = threading.Thread(target=self._run, name="motorctl-drivers", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread, waiting at most ``join_s`` (idempotent)."""
        self._stopping = True
        self._kick.set()
        wake, thread, self._thread = self._wake, self._thread, None
        if wake is not None:
            os.write(wake[1], b"!")
        if thread is not None:
            thread.join(self.join_s)
            if thread.is_alive():
                log.error("the driver poller did not stop within %.1f s", self.join_s)
                return
        if wake is not None:
            self._wake = None
            os.close(wake[0])
            os.close(wake[1])

    def _run(self) -> None:
        clock, kick, wake = self.clock, self._kick, self._wake
        fds = [fd for a in self.alerts if (fd := a.inputs.fileno()) is not None]
        while not self._stopping:
            nxt = self.poll_due(clock.now())
            wait = nxt - clock.now()
            if wait <= 0:
                continue
            if wake is None:
                if kick.wait(wait):
                    kick.clear()
                continue
            ready = select.select([wake[0], *fds], [], [], wait)[0]
            if wake[0] in ready:
                kick.clear()
