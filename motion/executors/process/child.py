"""The executor process: the step core in a process of its own, the daemon's child.

The child is a fresh interpreter with its own GIL (``python -c`` through :mod:`subprocess`,
``start.py``: it imports this module and what the step core needs, nothing of the daemon;
``motorctld`` starts it before the daemon's own imports). :func:`child_main` receives its
parameters and descriptors over a Unix socket, then :func:`run_child` enters SCHED_FIFO,
mlockall and its CPU (``RealtimeOptions``) and writes what it got (the real-time report,
each request granted, refused with its reason and fix, or not asked) into the shared
block for the daemon, opens its OWN step/dir and end-stop lines from
the picklable spec (``hal.registry.open_step_io``), maps the shared block (``rings.py``)
and runs a step core over it until the daemon clears the run cell or is gone: the compiled
one (``compiled_core.py``) or the Python one (``step_core.py`` over :class:`RingInbox`), as
``[step_thread] core`` and what is built and offered decide (:func:`choose_core`). It writes
which into the header's core cell before READY, with a note (why not the compiled core, or
why it cannot start at all) that the daemon logs.

A byte on the daemon's wake-up pipe wakes it (it sleeps there while nothing is due); it
writes a byte on the event pipe after each event, and its end of that pipe, closed when it
ends however it ends, tells the daemon it is gone.

Owner: the process's main thread, the only one it runs.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import select
import socket
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from motorctl.hal.compiled_lines import ChardevLines
from motorctl.hal.interfaces import Clock, HalError, MonotonicClock, StepIO
from motorctl.hal.registry import config_sections, open_step_io
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.executors.base import AxisLimits, ExecEvent, to_ticks
from motorctl.motion.executors.core_cells import CoreInbox
from motorctl.motion.executors.process import start as process_start
from motorctl.motion.executors.process.rings import (
    BAD_RECORD_S,
    CORE_CELL,
    CORES,
    EXIT_NO_CORE,
    NOTE,
    PID_CELL,
    READY_CELL,
    REALTIME,
    RUN_CELL,
    STEP_CORES,
    Layout,
    Ring,
    Shared,
    bad_record_text,
    event_fields,
    segment_of,
    segment_problem,
    stop_problem,
    torn_problem,
)
from motorctl.motion.executors.step_core import StepCore
from motorctl.motion.latency import LatencyStats
from motorctl.motion.rt import RealtimeOptions, enter_realtime

if TYPE_CHECKING:
    from motorctl.dataclass_code import CodeCache


class RingInbox(CoreInbox):
    """The core's inbox filled from the rings (the child, or a test on a virtual clock).

    A record is checked before it is queued; a bad one (see the module's doc) is queued in
    ``faults`` instead, for the core to fault its motor. ``clock`` times how long a record
    has been announced but not whole."""

    def __init__(self, shared: Shared, clock: Clock, bad_record_s: float = BAD_RECORD_S) -> None:
        super().__init__(shared.layout.motors)
        self.shared = shared
        self.clock = clock
        self.bad_after = to_ticks(bad_record_s)
        self.torn = torn_problem(bad_record_s)
        # per ring: [tail of the record seen not whole, since (ticks), reads]
        self._watch = [[-1, 0, 0] for _ in range(len(shared.segs) + 1)]

    def _get(self, ring: Ring, watch: list[int]) -> tuple[Any, ...] | None:
        """The next whole record; None: none (yet); ``()``: a bad one, taken."""
        rec = ring.get()
        if rec is not None:
            watch[0] = -1
            return rec
        tail = ring.cells[1]
        if tail >= ring.cells[0]:
            return None  # empty
        now = self.clock.now_ns()
        if watch[0] != tail:
            watch[:] = [tail, now, 1]
            return None
        watch[2] += 1
        if watch[2] < 2 or now - watch[1] < self.bad_after:
            return None
        watch[0] = -1
        ring.cells[1] = tail + 1  # the consumer's own cell: the ring moves on
        return ()

    def pull(self) -> None:
        sh = self.shared
        stops = sh.stops
        motors = len(self.queues)
        while stops.pending():
            rec = self._get(stops, self._watch[-1])
            if rec is None:
                break
            if not rec:
                self.faults.append((-1, bad_record_text("stop", self.torn)))
                continue
            motor, gen, cut = rec
            problem = stop_problem(motor, gen, cut, motors)
            if problem is not None:
                who = motor if 0 <= motor < motors else -1
                self.faults.append((who, bad_record_text("stop", problem)))
                continue
            self.stops.append((motor, gen, cut))
        for m, ring in enumerate(sh.segs):
            if not ring.pending():
                continue
            q = self.queues[m]
            watch = self._watch[m]
            while len(q) < 64:
                rec = self._get(ring, watch)
                if rec is None:
                    break
                if not rec:
                    self.faults.append((m, bad_record_text("step segment", self.torn)))
                    continue
                problem = segment_problem(*rec)
                if problem is not None:
                    self.faults.append((m, bad_record_text("step segment", problem)))
                    continue
                q.append(segment_of(rec))


def _die_with_parent(parent: int) -> None:
    """prctl(PR_SET_PDEATHSIG, SIGKILL): the kernel kills us when the daemon dies; if it
    died before that (we have another parent already), exit at once."""
    import ctypes
    import signal

    libc = ctypes.CDLL(None, use_errno=True)  # the interpreter's own libc (no ldconfig run)
    if libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG)")
    if os.getppid() != parent:
        raise SystemExit("motorctld executor: the daemon is gone")


def child_main(channel: socket.socket, parent: int, title_note: str, codes: CodeCache) -> None:
    """The executor process's entry (``start.py``'s bootstrap, once this module is
    imported; ``parent``: the daemon's PID; ``title_note``: what naming the process for
    ``ps`` could not do, logged once it runs): wait for the parameters of :func:`run_child`
    and the descriptors named in them (``fds``: their names, in the order they came), then
    run. Dismissed (the socket ended without them): exit quietly. ``codes``: the compiled
    dataclass methods the bootstrap imported this module with, used for those modules too."""
    _die_with_parent(parent)  # from now on, however the daemon ends (gone already: exit)
    # while the daemon is still starting: the modules of the config sections that the
    # parameters carry (in the hardware spec; none imports a hardware library)
    with codes.use():
        config_sections()
    codes.release()  # before the memory is locked (run_child)
    # and the collector's look at all of it, while waiting too (no automatic collection
    # since the bootstrap's first line, start.py): the collection before READY (_ready)
    # then looks only at what came after (the parameters, the lines, the core)
    import gc

    gc.collect()
    gc.freeze()
    got = process_start.receive(channel)
    if got is None:
        return
    params, fds = got
    named = dict(zip(params.pop("fds"), fds, strict=True))
    spec = params.pop("spec")
    options = {key: named.pop(key) for key in params.pop("step_io_fds")}
    run_child(
        parent=parent,
        spec=replace(spec, options={**spec.options, **options}),
        title_note=title_note,
        **named,
        **params,
    )


def run_child(
    parent: int,
    shm_fd: int,
    motors: int,
    lines: int,
    backend: str,
    spec: HardwareSpec,
    limits: Sequence[AxisLimits],
    rt: RealtimeOptions,
    spin_s: float,
    late_threshold_s: float,
    coalesce_s: float,
    wake_fd: int,
    event_fd: int,
    core: str,
    title_note: str = "",
) -> None:
    """The executor process: real-time set-up, own lines, then the step loop on the step
    core ``core`` asks for (:func:`choose_core`). ``shm_fd``, ``wake_fd`` and ``event_fd``
    are inherited descriptors (the shared block, the read end of the daemon's wake-up pipe,
    the write end of the event pipe)."""
    import gc
    import signal

    # The daemon decides when we stop: a service manager's SIGTERM goes to the whole control
    # group, and an executor dying of it would fault every motor (positions lost) before the
    # daemon's orderly shutdown ramps them down and writes the state.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    logging.basicConfig(level=logging.INFO, format="motorctld executor %(levelname)s: %(message)s")
    if title_note:  # ps shows the interpreter's command line or name instead
        logging.getLogger("motorctl.executor").warning(
            "%s not named in ps: %s", process_start.TITLE, title_note
        )
    got = enter_realtime(rt, "the step executor process")
    layout = Layout(motors, lines)
    shm = SharedBlock.attach(shm_fd, layout.size, "motorctl-executor")
    shared = Shared(shm, layout)
    report = json.dumps(got.as_dict()).encode()  # TEXT_MAX keeps it within REALTIME
    shared.realtime[: len(report)] = report[: REALTIME - 1]
    io = open_step_io(backend, spec, MonotonicClock(), None)
    if len(io.inputs.names) > lines:
        raise HalError(f"the step IO has {len(io.inputs.names)} inputs, room for {lines}")
    for m, (lo, hi) in enumerate(io.endstops):
        shared.endmap[2 * m] = -1 if lo is None else lo
        shared.endmap[2 * m + 1] = -1 if hi is None else hi
    header = shared.header
    chosen, note = choose_core(core, io)
    text = note.encode()[: NOTE - 1]
    shared.note[: len(text)] = text
    if chosen is None:  # the daemon reads the note once our end of the event pipe closes
        io.close()
        shared.release()
        shm.close()
        raise SystemExit(EXIT_NO_CORE)
    header[CORE_CELL] = CORES.index(chosen)
    header[PID_CELL] = os.getpid()
    os.set_blocking(event_fd, False)
    os.set_blocking(wake_fd, False)
    if chosen == "compiled":
        from motorctl.motion.executors.compiled_core import CompiledStepCore

        compiled = CompiledStepCore(
            io,
            limits,
            shared,
            late_threshold_s=late_threshold_s,
            spin_s=spin_s,
            coalesce_s=coalesce_s,
        )
        _ready(header, event_fd, gc)
        try:
            compiled.run(wake_fd, event_fd, parent)
        finally:
            compiled.halt_all()
            compiled.close()
            io.close()
            shared.release()
            shm.close()
        return
    inbox = RingInbox(shared, io.clock)

    def emit(ev: ExecEvent) -> None:
        shared.events.put(*event_fields(ev))
        with contextlib.suppress(BlockingIOError):
            os.write(event_fd, b"e")

    runner = StepCore(
        io,
        limits,
        inbox,
        emit,
        positions=shared.positions,
        levels=shared.levels,
        counters=shared.counters,
        stats=LatencyStats(late_threshold_s, shared.latency),
        motor_cells=shared.motor_cells,
        spin_s=spin_s,
        coalesce_s=coalesce_s,
    )

    def wait(timeout: float) -> None:
        if os.getppid() != parent:  # the daemon is gone (PDEATHSIG is the first guard)
            header[RUN_CELL] = 0
            return
        r, _, _ = select.select([wake_fd], [], [], timeout)
        if r:
            with contextlib.suppress(BlockingIOError):
                if os.read(wake_fd, 4096) == b"":  # the daemon's end is closed: it is gone
                    header[RUN_CELL] = 0

    _ready(header, event_fd, gc)
    try:
        runner.run(lambda: bool(header[RUN_CELL]), wait)
    finally:
        runner.halt_all()
        io.close()
        shared.release()
        shm.close()


def _ready(header: memoryview, event_fd: int, gc: Any) -> None:
    """Ready when the loop starts (not before the collection: the daemon plans the first
    steps a few ms ahead as soon as start() returns). The daemon reads READY (and so the
    end-stop map, the core cell and the note before it) only after this byte: the pipe
    orders our stores before its loads on a weakly ordered CPU too."""
    gc.collect()
    gc.freeze()
    gc.disable()
    header[READY_CELL] = 1
    with contextlib.suppress(BlockingIOError):
        os.write(event_fd, b"r")


def choose_core(wanted: str, io: StepIO) -> tuple[str | None, str]:
    """The step core to run over ``io`` for ``[step_thread] core = wanted``, and a note
    for the daemon's log: "python" asked for; "compiled" when it is built and the backend
    hands over its lines, else, for "auto", "python" with the reason (for "compiled": None,
    the process cannot start, the note says why)."""
    if wanted == "python":
        return "python", 'as [step_thread] core = "python" asks'
    if wanted not in STEP_CORES:
        return None, f"[step_thread] core = {wanted!r}: no such step core"
    from motorctl.motion.executors import compiled_core

    why = compiled_core.unavailable(io)
    if why is None:
        lines = io.compiled
        what = "GPIO character devices" if isinstance(lines, ChardevLines) else "the mock"
        return "compiled", f"its lines: {what}"
    if wanted == "compiled":
        return None, f'[step_thread] core = "compiled", but {why}'
    return "python", f"not the compiled core: {why}"
