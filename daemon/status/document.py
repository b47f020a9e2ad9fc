"""The status document, built in this one module: what ``motorctld --status``, the status
socket's subscribers, systemd's STATUS= line, the metrics and the monitor all read
(docs/status.md says what each field means).

:func:`status_document` builds it from the parts of a running daemon (:class:`Parts`, the
assembler's ``Daemon`` in practice): its motors, step executor, link, trace, state file,
pins and DC motor; :func:`summary_line` turns a document into systemd's one-line STATUS=.
:class:`StatusDocument` builds the documents of one frequent reader (the status server:
every one-shot read and subscription) and takes what is known not to have changed from the
document before; daemon/status/encoder.py then encodes only what changed. So a read costs
what changed since the last one (bench/status_rate.py, docs/timing.md).

Threads: :func:`status_document` runs on the status server's thread and the STATUS= line's
(daemon/service.py), never holding the motion lock: each field is read whole from a
snapshot of its owner (the executor's counters and histogram are its own snapshots), so a
status read never delays planning, let alone a step. A :class:`StatusDocument` belongs to
one thread (the status server's). :func:`summary_line` is pure.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from motorctl import __version__
from motorctl.daemon.config import Config
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.link.loop import Link
from motorctl.daemon.refusals import Refusals
from motorctl.daemon.state.persistence import Persistence
from motorctl.hal.interfaces import HalError, Hardware, Pin
from motorctl.motion.dc import DcMotor
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import Executor
from motorctl.motion.profile import Trajectory
from motorctl.motion.rt import RealtimeReport

if TYPE_CHECKING:  # a trace's modules are imported only when one is asked for
    from motorctl.daemon.link.recorder import TraceRecorder


class Parts(Protocol):
    """What the document is read from (the assembler's ``Daemon``)."""

    @property
    def config(self) -> Config: ...

    @property
    def hw(self) -> Hardware: ...

    @property
    def engine(self) -> MotionEngine: ...

    @property
    def dispatcher(self) -> Dispatcher: ...

    @property
    def persistence(self) -> Persistence: ...

    @property
    def link(self) -> Link | None: ...

    @property
    def trace(self) -> TraceRecorder | None: ...

    @property
    def started(self) -> float: ...  # time.monotonic() at the start


#: a document younger than this is the answer again while nothing happened since
#: (:class:`StatusDocument`): what frequent readers get
FRESH_S = 0.010


class StatusDocument:
    """The status documents of the status server's readers: a frequent reader gets the
    last document again while nothing has happened since, and each new document takes from
    the last the parts known not to have changed.

    - **The same document again**, when the last one is younger than ``FRESH_S`` and
      nothing has happened since it was begun (:meth:`moment`): the motion lock not
      released (every change of a motor, its queue, a fault, a stop, the DC motor is made
      under it: ``ChangeLock``, motion/engine.py), no answer taken for the host (counted
      after everything its command changed: ``LinkSession.outputs``), no turn of the link's
      loop ended, the state file neither written nor failed, the executor not dead. Each
      count moves on only after the change it stands for is whole, and is read before the
      document is begun: so a change under way while a document is built makes the next
      read build anew, and a reader that caused a change (its command answered, a
      WaitMoved released when the move ended) or saw one never gets a document from
      before it. What moves on meanwhile (positions and speeds of moving motors, the step
      counters and their lateness, the clock's fields, an input's level) is as of the
      document's ``monotonic_s``. A reader that asks less often than every ``FRESH_S``
      (``motorctld --status``, the monitor's updates, a metrics scrape) always gets a new
      one; a reader that asks 1,000 times a second gets one every ``FRESH_S`` at most, and
      each read costs the daemon little more than the socket's work (bench/status_rate.py).
      A histogram is always read anew.
    - **Parts taken again**: the link's status, while its loop has not turned and no
      answer was taken (the same counts); the executor's real-time report as a dict, while
      it is the same report (it is written once, at READY).

    The server encodes a document again only when it is not the one before
    (daemon/status/server.py), and then only its parts that changed
    (daemon/status/encoder.py). Called as the server's status source:
    ``StatusDocument(daemon)(histogram)``; ``clock``: seconds, monotonic."""

    def __init__(self, parts: Parts, clock: Callable[[], float] = time.monotonic) -> None:
        self.parts = parts
        self.clock = clock
        self._link: tuple[tuple[int, int, int], dict[str, Any]] | None = None
        self._realtime: tuple[RealtimeReport, dict[str, Any]] | None = None
        self._last: tuple[float, tuple[Any, ...], dict[str, Any]] | None = None

    def __call__(self, histogram: bool = False) -> dict[str, Any]:
        if histogram:
            return status_document(self.parts, True, self)
        moment, now, last = self.moment(), self.clock(), self._last
        if last is not None and now - last[0] < FRESH_S and last[1] == moment:
            return last[2]
        doc = status_document(self.parts, False, self)
        self._last = (now, moment, doc)
        return doc

    def moment(self) -> tuple[Any, ...]:
        """The counts that move on when something happens (not as time goes by), each after
        the change it stands for: read before a document is begun."""
        p = self.parts
        writer = p.persistence.writer
        return (
            p.engine.lock.releases,
            None if p.link is None else link_moment(p.link),
            p.engine.executor_died,
            p.dispatcher.refusals.answered,
            writer.writes,
            writer.errors,
            p.persistence.save_errors,
        )

    def link(self, link: Link) -> dict[str, Any]:
        moment = link_moment(link)  # before the status: a change under way is seen again
        if self._link is None or self._link[0] != moment:
            self._link = (moment, link_status(link.status()))
        return self._link[1]

    def realtime(self, report: RealtimeReport | None) -> dict[str, Any] | None:
        if report is None:
            return None
        if self._realtime is None or self._realtime[0] is not report:
            self._realtime = (report, report.as_dict())
        return self._realtime[1]


def link_moment(link: Link) -> tuple[int, int, int]:
    """What moves on when the link's status may have changed: its loop's turns (counted
    when one is over, daemon/link/loop.py), its waits (counted before each ``poll()``: what
    a turn changed before it waits, such as back pressure counted, is not left unseen for
    as long as the host keeps it waiting) and the answers taken for the host."""
    return link.turns, link.waits, link.session.outputs


def status_document(
    parts: Parts, histogram: bool = False, reader: StatusDocument | None = None
) -> dict[str, Any]:
    """A snapshot for the status socket, taken WITHOUT the motion lock: each field is
    read whole (the executor's counters and histogram are its own snapshots), so a
    status read never delays planning, let alone a step. Its cost is bounded (the
    lateness percentiles come from the histogram's blocks), except ``histogram``: the
    step edges' whole lateness histogram, ``steps.histogram_us`` (non-empty 1 us bins,
    up to 20,001), for the benchmarks that ask for it. ``reader``: a frequent reader's
    :class:`StatusDocument`, whose parts known unchanged are taken again."""
    executor = parts.engine.executor
    motors: list[dict[str, Any]] = [
        {
            "index": m.index,
            "name": m.params.name,
            "state": m.state.value,
            "position": m.position,
            "queued": len(m.queue),
            "fault": m.fault,
            "position_lost": m.position_lost,
            "waypoints": len(m.waypoints),
            "faults": dict(m.faults),
            "timing": {
                **executor.motor_timing(m.index),
                "microsteps": m.params.microsteps,
                "max_lag_full_steps": m.params.max_lag_full_steps,
            },
            "soft_stops": {
                "count": m.soft_stops,
                "takeover_ms": [round(t * 1000, 3) for t in m.takeover_s],
                "takeover_steps": list(m.takeover_steps),
            },
        }
        for m in list(parts.engine.motors)
    ]
    now = parts.engine.clock.now()
    for doc, m in zip(motors, parts.engine.motors, strict=True):
        doc["speed"] = motor_speed(m.traj, executor.motor_time(m.index, now))
    health = executor.health()
    steps = dict(health.latency)
    steps.update(health.counters)
    stats = executor.step_lateness()
    if histogram and stats is not None:  # the step executor's, with or without ramps
        steps["histogram_us"] = stats.histogram()
    rt = executor.realtime()
    realtime = reader.realtime(rt) if reader is not None else None if rt is None else rt.as_dict()
    out: dict[str, Any] = {
        "version": __version__,
        "motors": motors,
        "steps": steps,
        "executor": {
            "alive": health.alive,
            "reason": health.reason,
            "kind": step_executor_kind(parts.config, executor),
            "core": executor.step_core(),
            "pid": getattr(executor, "pid", None),
            "realtime": realtime,
        },
        "clamped": dict(parts.dispatcher.clamped),
        "hard_stops": parts.engine.stop_wait_status(),
        "state": parts.persistence.status(),
        "pins": pin_status(parts.hw.pins),
        "dc": dc_status(parts.engine.dc, now),
    }
    mono = time.monotonic()
    out.update(
        monotonic_s=mono, uptime_s=round(mono - parts.started, 3), unix_s=round(time.time(), 3)
    )
    if parts.link is not None:
        out["link"] = (
            reader.link(parts.link) if reader is not None else link_status(parts.link.status())
        )
    if parts.trace is not None:
        out["trace"] = parts.trace.status()
    drivers = [d for s in parts.hw.steppers if (d := s.driver.stats()) is not None]
    if drivers:  # SPI driver chips: polls, SPI status flag counts, faults, warnings
        out["drivers"] = drivers
    add_errors(out, parts.dispatcher.refusals)
    return out


#: the link's processing summary under names that say what they count: reads (not steps);
#: reads whose answers took longer than the target (bench/latency.py's p99 target), not
#: "late" ones: nothing was due
PROCESSING_NAMES = {"steps": "reads", "late": "over_target", "late_threshold_us": "target_us"}


def link_status(link: dict[str, Any]) -> dict[str, Any]:
    """The link's status with its processing summary's names said (``PROCESSING_NAMES``)."""
    processing = link.get("processing")
    if isinstance(processing, dict):
        link["processing"] = {PROCESSING_NAMES.get(k, k): v for k, v in processing.items()}
    return link


def add_errors(doc: dict[str, Any], refusals: Refusals) -> None:
    """The error answers with their reasons (daemon/refusals.py): each motor's last one,
    ``motors[].last_error``, and ``errors``: how many, how many the journal's limit held
    back, the last one and the last one not tied to a motor (docs/status.md)."""
    for motor in doc["motors"]:
        motor["last_error"] = refusals.motor_status(motor["index"])
    doc["errors"] = refusals.status()


def motor_speed(traj: Trajectory | None, now: float) -> float:
    """The planned speed at ``now`` in step/s, signed (0 without a trajectory)."""
    return 0.0 if traj is None else round(traj.velocity(now), 1)


def pin_status(pins: dict[int, Pin]) -> list[dict[str, Any]]:
    """Each IO pin: number, output or not, level (an input is read now; None if that
    failed, ``error`` says why)."""
    out: list[dict[str, Any]] = []
    for number, pin in sorted(pins.items()):
        entry: dict[str, Any] = {"number": number, "output": pin.is_output}
        try:
            entry["level"] = pin.read()
        except (HalError, OSError) as exc:
            entry.update(level=None, error=str(exc))
        out.append(entry)
    return out


def dc_status(dc: DcMotor | None, now: float) -> dict[str, Any] | None:
    """The DC motor's bridge state and the time left of its run; None: no DC motor."""
    if dc is None:
        return None
    deadline = dc.deadline
    return {
        "state": dc.bridge.state.value,
        "running": deadline is not None,
        "left_s": None if deadline is None else round(max(0.0, deadline - now), 3),
    }


def step_executor_kind(config: Config, executor: Executor) -> str:
    """``[step_thread] executor``, or "none" on a machine whose every motor runs on its
    TMC5160's own ramp (no step executor at all: none that times STEP edges)."""
    return config.step_thread.executor if executor.times_steps else "none"


def summary_line(status: dict[str, Any]) -> str:
    """systemd's STATUS=: motors moving/faulted/lost, frames served, errors, real time
    refused, state file."""
    motors = status.get("motors", [])
    moving = sum(1 for m in motors if m.get("state") not in ("idle", "fault"))
    faulted = [str(m.get("index")) for m in motors if m.get("fault")]
    lost = sum(1 for m in motors if m.get("position_lost"))
    parts = [f"{len(motors)} motors: {moving} moving"]
    parts[0] += f", faulted {','.join(faulted)}" if faulted else ", none faulted"
    if lost:
        parts[0] += f", {lost} to home"
    link = status.get("link")
    if isinstance(link, dict):
        counters = link.get("counters", {})
        errors = sum(
            v
            for k, v in counters.items()
            if isinstance(v, int) and (k.endswith("_errors") or k.startswith("sent_"))
        )
        parts.append(f"{counters.get('responses', 0)} frames served, {errors} errors")
        device = link.get("device") or "?"
        if link.get("peer") == "gone":
            parts.append(f"SERIAL DEVICE {device} GONE, reopening it when it is back")
        elif link.get("peer") == "waiting":
            parts.append(f"WAITING FOR SERIAL DEVICE {device} (not there yet)")
    executor = status.get("executor")
    rt = executor.get("realtime") if isinstance(executor, dict) else None
    if isinstance(rt, dict) and rt.get("refused"):
        what = ", ".join(str(rt.get(n, {}).get("what", n)) for n in rt["refused"])
        parts.append(f"REAL TIME REFUSED ({what}): steps best effort, see motorctld --status")
    state = status.get("state")
    if isinstance(state, dict) and not state.get("ok", True):
        parts.append("STATE NOT SAVED: " + str(state.get("last_error")))
    return "; ".join(parts)
