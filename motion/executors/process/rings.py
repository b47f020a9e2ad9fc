"""The process step executor's shared block: its layout, its rings and their records.

The block's layout, the rings and the records that cross them are one contract between the
daemon (``parent.py``) and the executor process (``child.py``, and the compiled core in
``csrc/rings.c``): the memory ordering below holds only if writer and reader agree to the
byte, so both take it from here and nowhere else.

The two processes share one block of anonymous shared memory (:mod:`motorctl.hal.shm`, a
memfd the child receives as a descriptor): it has no name to remove, the kernel frees it
when both processes are gone however they end (``kill -9`` of either included; the child
dies with the daemon, ``PR_SET_PDEATHSIG``), so no resource-tracker process runs. The block
(:class:`Layout`, seen through :class:`Shared`) holds:

- header cells: run flag, READY, the child's PID, which step core it runs (the child's
  note beside them: why not the compiled core, or why it cannot start), and what real
  time it got (its :class:`~motorctl.motion.rt.RealtimeReport` as JSON);
- counters, positions, end-stop levels and map, the latency histogram, the per-motor cells
  (the child writes; the daemon reads snapshots, no lock);
- per motor a single-producer single-consumer ring of step segments (daemon -> child);
- one ring of stops (daemon -> child) and one of events (child -> daemon).

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
- The one thing read in an order is the start-up: the child writes the end-stop map, its
  real-time report, its note and core cell, then READY, then a byte on the event pipe, and
  the daemon reads READY (and then the rest) only after reading that byte; the pipe orders
  them as it orders the rings' wake-ups.

A torn slot is taken only if its CRC-32 matches by chance: never for a difference within
32 consecutive bits (a previous lap's sequence number), 1 in 2**32 for any other mix, and
a mix is only visible for the moment a store takes to propagate. The check adds about
0.3 us per record on each side (``bench/rings.py``); records are segments, not steps.

Bad records (a stray write, a bug): a record of the daemon's rings still not whole after
``BAD_RECORD_S`` and two reads or more, or whole with a field no planner makes
(:func:`segment_problem`, :func:`stop_problem`: bounds that also keep the step core's tick
arithmetic far from overflow), is taken and reported as a FAULT of its motor (of every
motor for a stop record whose motor is unknown), counted in ``bad_records``; never a crash,
a hang or a step. Both step cores keep this rule (the Python one through ``child.py``'s
:class:`~motorctl.motion.executors.process.child.RingInbox`, the compiled one in
``csrc/rings.c``).

Owners: nothing here has state of its own; a :class:`Ring` has one producer and one
consumer, each in its own process (or thread), and every cell one writer.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, Final

from motorctl.hal.shm import SharedBlock
from motorctl.motion.executors.base import ExecEvent, ExecEventKind, from_ticks, to_ticks
from motorctl.motion.executors.core_cells import COUNTER_NAMES, MOTOR_CELLS
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.latency import CELLS

SEG_RING = 4096
STOP_RING = 256
EVENT_RING = 1024
SEG_RECORD = struct.Struct("<qqqqqqqq")  # seq, first, interval, count, add, direction, gen, flags
STOP_RECORD = struct.Struct("<qqqq")  # seq, motor, gen, cut (-1: a hard stop)
# seq, kind, motor, gen, position, t_ns, direction, mark, speed, text
EVENT_RECORD = struct.Struct("<qqqqqqqqd120s")
EVENT_KINDS = list(ExecEventKind)
FLAG_LAST, FLAG_WATCH, FLAG_RELEASE = 1, 2, 4

# header cells (int64)
RUN_CELL, READY_CELL, PID_CELL, CORE_CELL = 0, 1, 2, 3
HEADER_CELLS = 8
#: the CORE_CELL's values: which step core the child runs (0: not yet known)
CORES = ("", "python", "compiled")
#: the step cores [step_thread] core may ask for; the first is its default
STEP_CORES: Final = ("auto", "compiled", "python")
#: bytes of the child's note to the daemon: why it runs the Python core, or cannot start
NOTE = 256
#: bytes of the child's real-time report (JSON, NUL-padded): what it asked for and got
REALTIME = 4096
#: the executor process's exit status when it cannot run the step core the config asks for
#: (the daemon reads the note then)
EXIT_NO_CORE = 3
#: a record announced but still not whole this long (and over two reads or more) is bad: a
#: store takes nanoseconds to show, never this long (see "bad records" above)
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
    intervals below 2**34 ns that never go negative (csrc/rings.c, the same rule)."""
    if not 0 <= gen < _LIM_GEN:
        return f"generation {gen}"
    if flags & ~(FLAG_LAST | FLAG_WATCH | FLAG_RELEASE):
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
    kind, motor, gen, position, t_ns, direction, mark, speed, text = rec
    return ExecEvent(
        EVENT_KINDS[kind],
        motor,
        gen,
        position,
        from_ticks(t_ns),
        direction,
        speed,
        text.rstrip(b"\0").decode(errors="replace"),
        mark,
    )


def segment_fields(seg: StepSegment) -> tuple[int, ...]:
    """A segment as a record's fields (after the sequence number), as the daemon puts it."""
    flags = (
        (FLAG_LAST if seg.last else 0)
        | (FLAG_WATCH if seg.watch else 0)
        | (FLAG_RELEASE if seg.release else 0)
    )
    return (seg.first, seg.interval, seg.count, seg.add, seg.direction, seg.gen, flags)


def segment_of(rec: tuple[Any, ...]) -> StepSegment:
    """A whole segment record's fields (checked by :func:`segment_problem`) as the segment."""
    first, interval, count, add, direction, gen, flags = rec
    return StepSegment(
        first,
        interval,
        count,
        add,
        direction,
        gen,
        bool(flags & FLAG_LAST),
        bool(flags & FLAG_WATCH),
        bool(flags & FLAG_RELEASE),
    )


def event_fields(ev: ExecEvent) -> tuple[Any, ...]:
    """An event as a record's fields (after the sequence number): its detail cut to the
    record's 120 bytes."""
    return (
        EVENT_KINDS.index(ev.kind),
        ev.motor,
        ev.gen,
        ev.position,
        to_ticks(ev.t),
        ev.direction,
        ev.mark,
        ev.speed,
        ev.detail.encode()[:120],
    )


class Layout:
    """Offsets of everything in the shared block (both processes compute the same)."""

    def __init__(self, motors: int, lines: int) -> None:
        self.motors, self.lines = motors, lines
        off = 0
        self.header = off
        off += HEADER_CELLS * 8
        self.note = off
        off += NOTE
        self.realtime = off
        off += REALTIME
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
        self.motor_cells = off  # per motor: shift, late-step figures (core_cells.MOTOR_CELLS)
        off += motors * MOTOR_CELLS * 8
        # rings: head, tail cells then records
        self.seg_rings = []
        for _ in range(motors):
            self.seg_rings.append(off)
            off += ring_size(SEG_RECORD, SEG_RING)
        self.stop_ring = off
        off += ring_size(STOP_RECORD, STOP_RING)
        self.event_ring = off
        off += ring_size(EVENT_RECORD, EVENT_RING)
        self.size = off


#: a ring's cells before its slots: head (the producer's), tail and retries (the consumer's)
RING_HEADER = 3 * 8

# Each slot is the record (its first field the sequence number) followed by the CRC-32 of the
# record's bytes and 4 zero bytes (slots stay 8-byte aligned). The CRC-32 of a whole slot
# whose check matches its record is this constant, whatever the record: the consumer checks a
# slot with one call over one copy of it.
SLOT_CHECK = struct.Struct("<I4x")
SLOT_RESIDUE = zlib.crc32(SLOT_CHECK.pack(zlib.crc32(b"")))


def ring_size(rec: struct.Struct, capacity: int) -> int:
    """Bytes a :class:`Ring` of ``capacity`` records of ``rec`` takes in the block."""
    return RING_HEADER + capacity * (rec.size + SLOT_CHECK.size)


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
        self.slot = rec.size + SLOT_CHECK.size
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
        self.buf[at : at + self.slot] = body + SLOT_CHECK.pack(zlib.crc32(body))
        self.cells[0] = head + 1
        return True

    def get(self) -> tuple[Any, ...] | None:
        tail = self.cells[1]
        if tail >= self.cells[0]:
            return None
        at = self.base + (tail % self.cap) * self.slot
        raw = self.buf[at : at + self.slot].tobytes()  # one copy: what is checked is used
        if zlib.crc32(raw) != SLOT_RESIDUE:
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
        self.header = buf[lay.header : lay.header + HEADER_CELLS * 8].cast("q")
        self.note = buf[lay.note : lay.note + NOTE]
        self.realtime = buf[lay.realtime : lay.realtime + REALTIME]
        self.counters = buf[lay.counters : lay.counters + len(COUNTER_NAMES) * 8].cast("q")
        self.positions = buf[lay.positions : lay.positions + lay.motors * 8].cast("q")
        self.levels = buf[lay.levels : lay.levels + max(lay.lines, 1) * 8].cast("q")
        self.endmap = buf[lay.endmap : lay.endmap + lay.motors * 2 * 8].cast("q")
        self.latency = buf[lay.latency : lay.latency + CELLS * 8].cast("q")
        mc = lay.motor_cells
        self.motor_cells = buf[mc : mc + lay.motors * MOTOR_CELLS * 8].cast("q")
        self.segs = [Ring(buf, off, SEG_RECORD, SEG_RING) for off in lay.seg_rings]
        self.stops = Ring(buf, lay.stop_ring, STOP_RECORD, STOP_RING)
        self.events = Ring(buf, lay.event_ring, EVENT_RECORD, EVENT_RING)

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
            self.realtime,
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
