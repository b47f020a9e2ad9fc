"""The ``process`` step executor: the step core in a process of its own.

Over 500 lines on purpose: the shared memory's layout, its rings and both processes'
sides of them are one contract (the memory ordering below holds only if writer and reader
agree to the byte), read and changed in one place.

The child (``python -c`` through :mod:`subprocess`, ``motion/executor_process_start.py``: a fresh
interpreter with its own GIL, which imports this module and what the step core needs,
nothing of the daemon; ``motorctld`` starts it before the daemon's own imports) receives its
parameters and descriptors over a Unix socket, enters SCHED_FIFO, mlockall and its CPU
(``RealtimeOptions``), opens its OWN step/dir and end-stop lines from the picklable spec
(``hal.registry.open_step_io``), and runs :class:`~motorctl.motion.step_core.StepCore`.

The two processes share one block of anonymous shared memory (:mod:`motorctl.hal.shm`, a
memfd the child receives as a descriptor): it has no name to remove, the kernel frees it
when both processes are gone however they end (``kill -9`` of either included; the child
dies with the daemon, ``PR_SET_PDEATHSIG``), so no resource-tracker process runs. The block
holds:

- header cells: run flag, heartbeat (the core's loop counter), counters, positions, end-stop
  levels, the latency histogram (the child writes; the daemon reads snapshots, no lock);
- per motor a single-producer single-consumer ring of step segments (daemon -> child);
- one ring of stops (daemon -> child) and one of events (child -> daemon).

A byte on a pipe wakes the other side (the child sleeps on it while nothing is due; the
daemon's event thread on its own pipe, whose end also says that the child is gone).

Memory ordering (x86-64 and ARM64 alike; Python has no memory barrier): ARM64 (a Raspberry
Pi 4/5) may make one process's stores visible to the other in any order and satisfy loads
out of order, so nothing here relies on hardware store or load order:

- Each ring (:class:`Ring`) has a head (written only by its producer), a tail and a retry
  count (only by its consumer). A record carries its sequence number and a CRC-32 over the
  sequence number and every field. The consumer copies a slot once and takes it only when
  the sequence number is the one it expects AND the CRC matches; a slot not completely
  visible yet (head or sequence number new, payload old or half new) stays where it is and
  is taken by a later pull -- at the latest after the producer's wake-up byte, which the
  kernel's pipe lock orders after the record's stores. Never dropped, never waited for;
  counted (the ring's retry cell, in ``--status`` as ``ring_retries_segments`` for the
  child's reads of segments and stops, ``ring_retries_reports`` for the daemon's reads of
  the child's reports).
- The consumer stores its tail only after that check, which depends on every byte it
  loaded; ARM64 never makes a store visible ahead of a branch it depends on, so the
  producer cannot reuse a slot still being read. The producer's stores of a slot likewise
  follow its check of the tail.
- Every other shared value (head, tail, retries, run flag, heartbeat, counters, positions,
  levels, end-stop map, histogram cells) is one aligned 8-byte cell read and written through a
  native ``'q'`` memoryview, which CPython packs with one fixed-size 8-byte ``memcpy``
  (``PACK_SINGLE`` in Objects/memoryobject.c; aarch64 gcc compiles it to one ``str`` of
  an x register): a single-copy atomic store on ARM64 and x86-64, so a reader sees the
  old or the new value, never a torn one. Counters and the histogram are snapshots, not
  records; nothing depends on their order.
- The one thing read in an order is the start-up: the child writes the end-stop map, then
  READY, then a byte on the event pipe, and the daemon reads READY (and later the map) only
  after reading that byte; the pipe orders them as it orders the rings' wake-ups.

A torn slot is taken only if its CRC-32 matches by chance: never for a difference within
32 consecutive bits (a previous lap's sequence number), 1 in 2**32 for any other mix, and
a mix is only visible for the moment a store takes to propagate. The check adds about
0.3 us per record on each side (``bench/rings.py``); records are segments, not steps.

Bad records (a stray write, a bug): a record of the daemon's rings still not whole after
``BAD_RECORD_S`` and two reads or more, or whole with a field no planner makes
(:func:`segment_problem`, :func:`stop_problem`: bounds that also keep the step core's tick
arithmetic far from overflow), is taken and reported as a FAULT of its motor (of every
motor for a stop record whose motor is unknown), counted in ``bad_records``; never a crash,
a hang or a step. Both step cores keep this rule (the compiled one in motion/csrc/rings.c).

The child runs the compiled step core (``motion/compiled_core.py``) or the Python one, as
``[step_thread] core`` and what is built and offered decide; it writes which into the
header's core cell before READY, with a note (why not the compiled core, or why it cannot
start at all) that the daemon logs.

If the child dies, the event thread notices at once (the end of the event pipe, whose only
writer it was) and reports DIED: every motor faults (E4, position lost) and health says why;
the service then exits non-zero.

Owners: in the daemon, the planner side (engine lock) writes the segment and stop rings and
drains the event ring; the event thread only waits and wakes the planner.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from motorctl.hal.interfaces import (
    ChardevLines,
    Clock,
    HalError,
    Hardware,
    MonotonicClock,
    StepIO,
)
from motorctl.hal.registry import config_sections, open_step_io
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion import executor_process_start
from motorctl.motion.executor_seam import (
    AxisLimits,
    ExecEvent,
    ExecEventKind,
    ExecutorHealth,
    from_ticks,
    to_ticks,
)
from motorctl.motion.latency import CELLS, LatencyStats
from motorctl.motion.rt import RealtimeOptions, enter_realtime
from motorctl.motion.segments import StepSegment
from motorctl.motion.step_core import COUNTER_NAMES, MOTOR_CELLS, CoreInbox, StepCore
from motorctl.motion.step_planner import StepExecutor

log = logging.getLogger("motorctl.executor")

SEG_RING = 4096
STOP_RING = 256
EVENT_RING = 1024
_SEG = struct.Struct("<qqqqqqqq")  # seq, first, interval, count, add, direction, gen, flags
_STOP = struct.Struct("<qqqq")  # seq, motor, gen, cut (-1: a hard stop)
# seq, kind, motor, gen, position, t_ns, direction, speed, text
_EVENT = struct.Struct("<qqqqqqqd120s")
_KINDS = list(ExecEventKind)
_LAST, _WATCH = 1, 2

# header cells (int64)
_RUN, _READY, _PID, _CORE = 0, 1, 2, 3
_HEADER = 8
#: the _CORE cell: which step core the child runs (0: not yet known)
CORES = ("", "python", "compiled")
#: bytes of the child's note to the daemon: why it runs the Python core, or cannot start
NOTE = 256
#: a record announced but still not whole this long (and over two reads or more) is bad: a
#: store takes nanoseconds to show, never this long (see "bad records" below)
BAD_RECORD_S = 0.5


_LIM_GEN = 1 << 62
_LIM_TICK = 1 << 59
_LIM_COUNT = 1 << 24
_LIM_IV = 1 << 34


def segment_problem(
    first: int, interval: int, count: int, add: int, direction: int, gen: int, flags: int
) -> str | None:
    """What is wrong with a whole segment record's fields, None when nothing: generations
    below 2**62 (the core's own block is 2**62), ticks below 2**59, at most 2**24 steps,
    intervals below 2**34 ns that never go negative (motion/csrc/rings.c, the same rule)."""
    if not 0 <= gen < _LIM_GEN:
        return f"generation {gen}"
    if flags & ~(_LAST | _WATCH):
        return f"flags {flags}"
    if not 0 <= count <= _LIM_COUNT:
        return f"count {count}"
    if count == 0:
        return None  # a marker: nothing is timed by it
    if direction not in (1, -1):
        return f"direction {direction}"
    if not 0 <= first < _LIM_TICK:
        return f"first step at tick {first}"
    if not 0 <= interval < _LIM_IV:
        return f"interval {interval}"
    if not -_LIM_IV < add < _LIM_IV or abs(add) * count >= _LIM_IV:
        return f"add {add} over {count} steps"
    if count >= 2 and interval + add * (count - 2) < 0:
        return f"intervals below 0 (interval {interval}, add {add}, count {count})"
    return None


def stop_problem(motor: int, gen: int, cut: int, motors: int) -> str | None:
    """What is wrong with a whole stop record's fields, None when nothing."""
    if not 0 <= motor < motors:
        return f"motor {motor}"
    if not 0 <= gen < _LIM_GEN:
        return f"generation {gen}"
    if cut != -1 and not 0 <= cut < _LIM_TICK:
        return f"cut at tick {cut}"
    return None


def bad_record_text(which: str, problem: str) -> str:
    """The FAULT's detail for a bad record (both step cores word it so)."""
    return f"bad {which} record in the executor's ring: {problem}"


def torn_problem(bad_after_s: float = BAD_RECORD_S) -> str:
    return f"not whole after {bad_after_s * 1000:.0f} ms (CRC-32 or sequence number wrong)"


def decode_event(rec: tuple[Any, ...]) -> ExecEvent:
    """An event record's fields (after the sequence number) as the event."""
    kind, motor, gen, position, t_ns, direction, speed, text = rec
    return ExecEvent(
        _KINDS[kind],
        motor,
        gen,
        position,
        from_ticks(t_ns),
        direction,
        speed,
        text.rstrip(b"\0").decode(errors="replace"),
    )


class Layout:
    """Offsets of everything in the shared block (both processes compute the same)."""

    def __init__(self, motors: int, lines: int) -> None:
        self.motors, self.lines = motors, lines
        off = 0
        self.header = off
        off += _HEADER * 8
        self.note = off
        off += NOTE
        self.counters = off
        off += len(COUNTER_NAMES) * 8
        self.positions = off
        off += motors * 8
        self.levels = off
        off += max(lines, 1) * 8
        self.endmap = off  # per motor: (min line, max line), -1 when not wired
        off += motors * 2 * 8
        self.latency = off
        off += CELLS * 8
        self.motor_cells = off  # per motor: shift, late-step figures (step_core.MOTOR_CELLS)
        off += motors * MOTOR_CELLS * 8
        # rings: head, tail cells then records
        self.seg_rings = []
        for _ in range(motors):
            self.seg_rings.append(off)
            off += ring_size(_SEG, SEG_RING)
        self.stop_ring = off
        off += ring_size(_STOP, STOP_RING)
        self.event_ring = off
        off += ring_size(_EVENT, EVENT_RING)
        self.size = off


#: a ring's cells before its slots: head (the producer's), tail and retries (the consumer's)
RING_HEADER = 3 * 8

# Each slot is the record (its first field the sequence number) followed by the CRC-32 of the
# record's bytes and 4 zero bytes (slots stay 8-byte aligned). The CRC-32 of a whole slot
# whose check matches its record is this constant, whatever the record: the consumer checks a
# slot with one call over one copy of it.
_CHECK = struct.Struct("<I4x")
_RESIDUE = zlib.crc32(_CHECK.pack(zlib.crc32(b"")))


def ring_size(rec: struct.Struct, capacity: int) -> int:
    """Bytes a :class:`Ring` of ``capacity`` records of ``rec`` takes in the block."""
    return RING_HEADER + capacity * (rec.size + _CHECK.size)


class Ring:
    """A single-producer single-consumer ring of fixed-size records in shared memory.

    ``rec`` is the record's struct, its first field an int64 sequence number (the
    caller's fields follow); the slot adds a CRC-32 over the whole record. Correct
    without any hardware ordering of the record's stores or loads (ARM64 gives none):

    - the consumer copies the slot ONCE and accepts it only when the copy's CRC matches
      AND its sequence number is the one it expects; anything else (not yet visible,
      stale from the previous lap, torn) is "not written yet": ``get`` returns None,
      the tail stays, and the next ``get`` (the next pull, at the latest after the
      producer's wake-up byte, whose pipe lock orders the stores before it) retries;
    - the consumer stores the tail only after that check, which depends on every byte
      it loaded (a control dependency: ARM64 never makes a store visible before the
      branch it depends on is resolved), so the producer cannot see the slot free while
      it is still being read; the producer's stores of a slot likewise follow its
      check of the tail;
    - head and tail are single aligned 8-byte cells written through a native 'q'
      memoryview (one 8-byte store, single-copy atomic on ARM64 and x86-64).

    :attr:`retries` counts the consumer's gets that found the next record announced (the
    head past it) but not complete or not yet its own (torn, stale): each is read again
    later. It is a third cell, written only by the consumer, so the other process can
    read it (the daemon reports the child's counts in its status).

    Owners: one producer and one consumer, each in its own process or thread; no
    method blocks, ``get`` and ``put`` never raise on a full, empty or incomplete ring.
    """

    def __init__(self, buf: memoryview, offset: int, rec: struct.Struct, capacity: int) -> None:
        if offset % 8 or rec.size % 8:
            raise ValueError(
                f"ring at {offset} with {rec.size}-byte records: not 8-byte "
                "aligned (head/tail and slots must be)"
            )
        self.buf = buf
        self.cells = buf[offset : offset + RING_HEADER].cast("q")  # [head, tail, retries]
        self.base = offset + RING_HEADER
        self.rec = rec
        self.slot = rec.size + _CHECK.size
        self.cap = capacity

    @property
    def retries(self) -> int:
        """Gets that found the next record announced but torn or stale (read again later)."""
        return int(self.cells[2])

    def free(self) -> int:
        return self.cap - (self.cells[0] - self.cells[1])

    def put(self, *fields: Any) -> bool:
        head = self.cells[0]
        if head - self.cells[1] >= self.cap:
            return False
        # the stores below follow the branch on the tail just loaded
        at = self.base + (head % self.cap) * self.slot
        body = self.rec.pack(head + 1, *fields)
        self.buf[at : at + self.slot] = body + _CHECK.pack(zlib.crc32(body))
        self.cells[0] = head + 1
        return True

    def get(self) -> tuple[Any, ...] | None:
        tail = self.cells[1]
        if tail >= self.cells[0]:
            return None
        at = self.base + (tail % self.cap) * self.slot
        raw = self.buf[at : at + self.slot].tobytes()  # one copy: what is checked is used
        if zlib.crc32(raw) != _RESIDUE:
            self.cells[2] += 1
            return None
        rec = self.rec.unpack_from(raw)
        if rec[0] != tail + 1:
            self.cells[2] += 1
            return None
        self.cells[1] = tail + 1  # only after the check on every loaded byte
        return rec[1:]

    def pending(self) -> bool:
        return bool(self.cells[1] < self.cells[0])

    def release(self) -> None:
        self.cells.release()


class Shared:
    """The shared block seen through typed views (either process)."""

    def __init__(self, shm: SharedBlock, layout: Layout) -> None:
        buf = shm.buf
        if buf is None:
            raise ValueError("shared memory closed")
        self.shm = shm
        self.layout = lay = layout
        self.header = buf[lay.header : lay.header + _HEADER * 8].cast("q")
        self.note = buf[lay.note : lay.note + NOTE]
        self.counters = buf[lay.counters : lay.counters + len(COUNTER_NAMES) * 8].cast("q")
        self.positions = buf[lay.positions : lay.positions + lay.motors * 8].cast("q")
        self.levels = buf[lay.levels : lay.levels + max(lay.lines, 1) * 8].cast("q")
        self.endmap = buf[lay.endmap : lay.endmap + lay.motors * 2 * 8].cast("q")
        self.latency = buf[lay.latency : lay.latency + CELLS * 8].cast("q")
        mc = lay.motor_cells
        self.motor_cells = buf[mc : mc + lay.motors * MOTOR_CELLS * 8].cast("q")
        self.segs = [Ring(buf, off, _SEG, SEG_RING) for off in lay.seg_rings]
        self.stops = Ring(buf, lay.stop_ring, _STOP, STOP_RING)
        self.events = Ring(buf, lay.event_ring, _EVENT, EVENT_RING)

    def ring_retries(self) -> dict[str, int]:
        """The consumers' retry counts: the child's reads of segments and stops (daemon ->
        child), the daemon's reads of the child's reports (child -> daemon)."""
        return {
            "ring_retries_segments": sum(r.retries for r in (*self.segs, self.stops)),
            "ring_retries_reports": self.events.retries,
        }

    def release(self) -> None:
        views = (
            self.header,
            self.note,
            self.counters,
            self.positions,
            self.levels,
            self.endmap,
            self.latency,
            self.motor_cells,
        )
        for view in views:
            view.release()
        for ring in (*self.segs, self.stops, self.events):
            ring.release()


# --------------------------------------------------------------------------- the child


class _ShmInbox(CoreInbox):
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
                first, interval, count, add, direction, gen, flags = rec
                problem = segment_problem(first, interval, count, add, direction, gen, flags)
                if problem is not None:
                    self.faults.append((m, bad_record_text("step segment", problem)))
                    continue
                q.append(
                    StepSegment(
                        first,
                        interval,
                        count,
                        add,
                        direction,
                        gen,
                        bool(flags & _LAST),
                        bool(flags & _WATCH),
                    )
                )


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


def child_main(channel: socket.socket, parent: int) -> None:
    """The executor process's entry (``motion/executor_process_start.py``'s bootstrap, once
    this module is imported; ``parent``: the daemon's PID): wait for the parameters of
    :func:`_child_main` and the descriptors named in them (``fds``: their names, in the
    order they came), then run. Dismissed (the socket ended without them): exit quietly."""
    _die_with_parent(parent)  # from now on, however the daemon ends (gone already: exit)
    # while the daemon is still starting: the modules of the config sections that the
    # parameters carry (in the hardware spec; none imports a hardware library)
    config_sections()
    got = executor_process_start.receive(channel)
    if got is None:
        return
    params, fds = got
    named = dict(zip(params.pop("fds"), fds, strict=True))
    spec = params.pop("spec")
    options = {key: named.pop(key) for key in params.pop("step_io_fds")}
    _child_main(
        parent=parent, spec=replace(spec, options={**spec.options, **options}), **named, **params
    )


def _child_main(
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
    core: str = "auto",
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
    enter_realtime(rt, "the step executor process")
    layout = Layout(motors, lines)
    shm = SharedBlock.attach(shm_fd, layout.size, "motorctl-executor")
    shared = Shared(shm, layout)
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
    header[_CORE] = CORES.index(chosen)
    header[_PID] = os.getpid()
    os.set_blocking(event_fd, False)
    os.set_blocking(wake_fd, False)
    if chosen == "compiled":
        from motorctl.motion.compiled_core import CompiledStepCore

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
    inbox = _ShmInbox(shared, io.clock)

    def emit(ev: ExecEvent) -> None:
        text = ev.detail.encode()[:120]
        shared.events.put(
            _KINDS.index(ev.kind),
            ev.motor,
            ev.gen,
            ev.position,
            to_ticks(ev.t),
            ev.direction,
            ev.speed,
            text,
        )
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
            header[_RUN] = 0
            return
        r, _, _ = select.select([wake_fd], [], [], timeout)
        if r:
            with contextlib.suppress(BlockingIOError):
                if os.read(wake_fd, 4096) == b"":  # the daemon's end is closed: it is gone
                    header[_RUN] = 0

    _ready(header, event_fd, gc)
    try:
        runner.run(lambda: bool(header[_RUN]), wait)
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
    header[_READY] = 1
    with contextlib.suppress(BlockingIOError):
        os.write(event_fd, b"r")


#: the executor process's exit status when it cannot run the step core the config asks for
EXIT_NO_CORE = 3


def choose_core(wanted: str, io: StepIO) -> tuple[str | None, str]:
    """The step core to run over ``io`` for ``[step_thread] core = wanted``, and a note
    for the daemon's log: "python" asked for; "compiled" when it is built and the backend
    hands over its lines, else, for "auto", "python" with the reason (for "compiled": None,
    the process cannot start, the note says why)."""
    if wanted == "python":
        return "python", 'as [step_thread] core = "python" asks'
    if wanted not in ("auto", "compiled"):
        return None, f"[step_thread] core = {wanted!r}: no such step core"
    from motorctl.motion import compiled_core

    why = compiled_core.unavailable(io)
    if why is None:
        lines = io.compiled
        what = "GPIO character devices" if isinstance(lines, ChardevLines) else "the mock"
        return "compiled", f"its lines: {what}"
    if wanted == "compiled":
        return None, f'[step_thread] core = "compiled", but {why}'
    return "python", f"not the compiled core: {why}"


# --------------------------------------------------------------------------- the daemon


class ProcessStepExecutor(StepExecutor):
    """The planner in the daemon, the step core in its own real-time process."""

    def __init__(
        self,
        hw: Hardware,
        backend: str,
        spec: HardwareSpec,
        limits: Sequence[AxisLimits],
        *,
        ahead_s: float = 0.05,
        lead_s: float = 0.003,
        max_error_s: float = 5e-6,
        spin_s: float = 200e-6,
        late_threshold_s: float = 100e-6,
        rt: RealtimeOptions | None = None,
        start_timeout_s: float = 30.0,
        process: executor_process_start.ExecutorProcess | None = None,
        core: str = "auto",
    ) -> None:
        """``process``: an executor process started earlier (``daemon/launch.py``), else
        one is started here. ``core``: the step core it runs, "auto" (the compiled one where
        it is built and the backend hands over its lines, else the Python one, with a
        warning), "compiled" (else it cannot start) or "python"."""
        if hw.clock.is_virtual:
            raise ValueError(
                "the process executor runs on the real clock; tests on a virtual "
                "clock use the thread executor"
            )
        super().__init__(hw.clock, limits, ahead_s=ahead_s, lead_s=lead_s, max_error_s=max_error_s)
        self.backend = backend
        self.spec = replace(spec, options={**spec.options, **hw.step_io_options})
        self.rt = rt or RealtimeOptions(priority=0, lock_memory=False)
        self.spin_s = spin_s
        self.coalesce_s = max_error_s  # a step may share an earlier pulse within the error
        self.late_threshold_s = late_threshold_s
        self.start_timeout_s = start_timeout_s
        self.core = core
        #: the step core the process runs ("compiled", "python"; None until started) and
        #: its note (why not the compiled one)
        self.core_name: str | None = None
        self.core_note = ""
        motors = len(limits)
        self.lines = 2 * len(spec.axes)
        self.layout = Layout(motors, self.lines)
        # zero-filled, anonymous: nothing to remove, whatever happens (see the module's doc)
        self.shm = SharedBlock.create(self.layout.size, "motorctl-executor")
        self.shared = Shared(self.shm, self.layout)
        self.stats = LatencyStats(late_threshold_s, self.shared.latency)
        self.motor_cells = self.shared.motor_cells
        self._step_io_fds = dict(hw.step_io_fds)
        # raw bytes on two pipes: only wake-ups, never messages. The child's ends (wake
        # read, event write) are closed here once it has them: the event pipe's end (EOF)
        # then says the child is gone
        self._wake_r, self._wake_w = os.pipe()
        self._event_r, self._event_w = os.pipe()
        self._child_fds: list[int] = [self._wake_r, self._event_w]
        os.set_blocking(self._wake_w, False)
        os.set_blocking(self._event_r, False)
        self._batching = False  # in service(): one wake-up byte for all its pushes
        self._kick_owed = False
        self.proc: subprocess.Popen[bytes] | None = None
        self._spawned = time.monotonic()  # (or earlier: a process started before)
        self.died: str | None = None
        self._died_reported = False
        self._closing = False
        self._watcher: threading.Thread | None = None
        self._closed: tuple[list[int], dict[str, int]] | None = None
        self.pending: list[list[StepSegment]] = [[] for _ in range(motors)]
        # the child runs from now on (if it was not started already, it starts now), while
        # the daemon builds the rest; start() waits for it
        self.shared.header[_RUN] = 1
        try:
            self._hand_over(process)
        except BaseException:
            self.close()
            raise

    # -- lifecycle -----------------------------------------------------------------------
    def _hand_over(self, process: executor_process_start.ExecutorProcess | None) -> None:
        """The process its parameters and descriptors (our copies are closed then)."""
        if process is None:
            try:
                process = executor_process_start.ExecutorProcess.start()
            except OSError as exc:
                raise HalError(
                    f"cannot start the step executor process ({sys.executable}): {exc}"
                ) from exc
            self._spawned = time.monotonic()
        self.proc = process.proc
        assert self.shm.fd is not None
        fds = {
            "shm_fd": self.shm.fd,
            "wake_fd": self._wake_r,
            "event_fd": self._event_w,
            **self._step_io_fds,
        }
        params = {
            "fds": list(fds),
            "step_io_fds": list(self._step_io_fds),
            "motors": self.layout.motors,
            "lines": self.lines,
            "backend": self.backend,
            "spec": self.spec,
            "limits": list(self.limits),
            "rt": self.rt,
            "spin_s": self.spin_s,
            "late_threshold_s": self.late_threshold_s,
            "coalesce_s": self.coalesce_s,
            "core": self.core,
        }
        with contextlib.suppress(OSError):  # it is gone already: start() says how it ended
            process.hand_over(params, list(fds.values()))
        self._forget_child_fds()  # the child has its own now

    def start(self) -> None:
        """Wait until the child is ready (at most ``start_timeout_s``), then watch it."""
        proc = self.proc
        if proc is None or self._watcher is not None or self._closed is not None:
            raise RuntimeError("the step executor process starts once, before close()")
        # READY is read only after the child's byte on the event pipe (see _child_main): the
        # end-stop map it wrote before is then visible here on ARM64 too
        deadline = self._spawned + self.start_timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                proc.kill()
                proc.wait(5)
                raise HalError(
                    f"the step executor process did not start within {self.start_timeout_s:.0f} s"
                )
            if not select.select([self._event_r], [], [], left)[0]:
                continue
            # the child's first byte on this pipe; event bytes after it are the watcher's
            try:
                byte = os.read(self._event_r, 1)
            except BlockingIOError:
                continue
            if byte == b"":  # its end closed: it exited
                code = proc.wait()
                note = self._note()
                if code == EXIT_NO_CORE and note:
                    raise HalError(f"the step executor cannot start: {note}")
                raise HalError(
                    f"the step executor process exited at start (code {code}); see the log above"
                )
            if self.shared.header[_READY]:
                break
        self.core_name = CORES[self.shared.header[_CORE]] or None
        self.core_note = self._note()
        if self.core_name == "python" and self.core != "python":
            log.warning("step core: python (%s)", self.core_note)
        else:
            log.info("step core: %s (%s)", self.core_name, self.core_note)
        self._watcher = threading.Thread(
            target=self._watch, name="motorctl-exec-watch", daemon=True
        )
        self._watcher.start()

    def _note(self) -> str:
        """The child's note (written before READY or before it exited)."""
        return bytes(self.shared.note).rstrip(b"\0").decode(errors="replace")

    def step_core(self) -> str | None:
        return self.core_name

    def _forget_child_fds(self) -> None:
        """Close this process's copies of the child's descriptors (its pipe ends, the block's
        memfd; the mapping stays)."""
        for fd in self._child_fds:
            os.close(fd)
        self._child_fds = []
        self.shm.forget_fd()

    def _watch(self) -> None:
        """Wake the planner on events; notice at once when the child dies: the event pipe
        ends (its only writer is gone, however it ended)."""
        proc = self.proc
        assert proc is not None
        while True:
            select.select([self._event_r], [], [])
            try:
                data = os.read(self._event_r, 4096)
            except BlockingIOError:
                continue
            if data:
                self.on_event()
                continue
            code = proc.wait()
            if not self._closing:
                self.died = f"step executor process {proc.pid} died (exit code {code})"
                log.error("%s: every motor faults, positions lost", self.died)
            self.on_event()
            return

    def close(self) -> None:
        if self._closed is not None:
            return
        self._closing = True
        self.shared.header[_RUN] = 0
        self._kick()
        if self.proc is not None:
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if self._watcher is not None:
            self._watcher.join(5)
            self._watcher = None
        # what is read after close comes from plain copies, not the block
        self._closed = ([int(x) for x in self.shared.positions], self._counters())
        cells = [int(self.shared.latency[i]) for i in range(CELLS)]
        self.stats = LatencyStats(self.late_threshold_s, cells)
        self.motor_cells = [int(x) for x in self.shared.motor_cells]
        self.shared.release()
        self._forget_child_fds()  # not started: they are still here
        self.shm.close()
        for fd in (self._wake_w, self._event_r):
            os.close(fd)

    @property
    def pid(self) -> int | None:
        """The executor process's PID (status, benchmarks)."""
        return None if self.proc is None else int(self.proc.pid)

    def kill_for_test(self, sig: int) -> None:
        """Send ``sig`` to the executor process (tests and benchmarks: stalls, death)."""
        assert self.proc is not None
        os.kill(self.proc.pid, sig)

    # -- the transport ---------------------------------------------------------------------
    def _push(self, motor: int, segments: list[StepSegment]) -> None:
        if self._closed is not None:
            return  # closed: nothing moves any more
        ring = self.shared.segs[motor]
        pending = self.pending[motor]
        pending.extend(segments)
        sent = 0
        for seg in pending:
            flags = (_LAST if seg.last else 0) | (_WATCH if seg.watch else 0)
            if not ring.put(
                seg.first, seg.interval, seg.count, seg.add, seg.direction, seg.gen, flags
            ):
                break
            sent += 1
        del pending[:sent]
        self._kick()

    def _push_stop(self, motor: int, gen: int, cut: int = -1) -> None:
        if self._closed is not None:
            return
        self.pending[motor] = [
            s for s in self.pending[motor] if s.gen > gen or (cut >= 0 and s.first < cut)
        ]
        if not self.shared.stops.put(motor, gen, cut):
            raise HalError("the step executor's stop ring is full")
        self._kick()

    def _kick(self) -> None:
        if self._batching:
            self._kick_owed = True
            return
        self._kick_owed = False
        with contextlib.suppress(BlockingIOError, OSError, ValueError):
            os.write(self._wake_w, b"k")

    def _raw_events(self) -> list[ExecEvent]:
        out: list[ExecEvent] = []
        if self._closed is not None:
            return out
        ring = self.shared.events
        while True:
            rec = ring.get()
            if rec is None:
                break
            out.append(decode_event(rec))
        if self.died is not None and not self._died_reported:
            self._died_reported = True
            out.append(ExecEvent(ExecEventKind.DIED, -1, -1, 0, self.clock.now(), detail=self.died))
        return out

    def service(self, now: float) -> float:
        """Top-ups of every motor, then one wake-up byte (a syscall) for all of them."""
        self._batching = True
        try:
            for m, pending in enumerate(self.pending):
                if pending:
                    self._push(m, [])
            return super().service(now)
        finally:
            self._batching = False
            if self._kick_owed:
                self._kick()

    # -- snapshots -------------------------------------------------------------------------
    def position(self, motor: int) -> int:
        if self._closed is not None:
            return self._closed[0][motor]
        return int(self.shared.positions[motor])

    def endstop_active(self, motor: int, direction: int) -> bool:
        if self._closed is not None:
            return False
        line = self.shared.endmap[2 * motor + (1 if direction > 0 else 0)]
        return line >= 0 and bool(self.shared.levels[line])

    def health(self) -> ExecutorHealth:
        if self._closed is not None:
            return ExecutorHealth(
                False,
                self._closed[1]["progress"],
                self.died,
                dict(self._closed[1]),
                self.stats.summary(),
            )
        alive = self.proc is not None and self.proc.poll() is None and self.died is None
        counters = self._counters()
        return ExecutorHealth(
            alive=alive,
            progress=counters["progress"],
            reason=self.died,
            counters=counters,
            latency=self.stats.summary(),
        )

    def _counters(self) -> dict[str, int]:
        """The step core's counters and the rings' retry counts, from the shared block."""
        counters = dict(zip(COUNTER_NAMES, self.shared.counters, strict=True))
        counters.update(self.shared.ring_retries())
        return counters

    def step_lateness(self) -> LatencyStats:
        return self.stats  # after close: a plain copy of the last cells
