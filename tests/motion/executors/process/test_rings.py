"""The shared block's rings of the process step executor (motion/executors/process/rings.py
``Ring``).

A weakly ordered CPU (ARM64) may show the consumer a slot in any mix of old and new bytes,
with the head and the sequence number already new; the consumer must take a record only
when it is completely there, and retry otherwise. These tests write exactly such slots by
hand (every word-level mix of the old and the new record, random byte-level mixes, a slot
overwritten by the next lap while being read) and run a randomised producer/consumer pair
between two real processes on POSIX shared memory.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import random
import struct
import time
import zlib
from multiprocessing import shared_memory
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.hal.shm import SharedBlock
from motorctl.motion.executors.process.rings import (
    EVENT_RECORD,
    SEG_RECORD,
    SLOT_CHECK,
    SLOT_RESIDUE,
    STOP_RECORD,
    Layout,
    Ring,
    Shared,
    ring_size,
)
from tests.support.executors import scratch_ring, show_slot, slot_bytes, slot_offset

DEADLINE_S = 60.0
TEXT = 120  # the event record's text field


def _seg(i: int) -> tuple[int, ...]:
    """A segment record's fields, distinct for every i (direction and flags repeat)."""
    return (10**9 + 7919 * i, 250_000 + i, 4000 + i, -3 - i, 1 if i % 2 else -1, 7 + i, i % 4)


def _event(i: int, text: bytes | None = None) -> tuple[Any, ...]:
    body = text if text is not None else f"event {i} ".encode() * (i % 13 + 1)
    return (i % 7, i % 3, 100 + i, -5 * i, 10**9 + i, 1, 7 - i, 4000.5 + i, body[:TEXT])


def _padded(text: bytes) -> bytes:
    return text + bytes(TEXT - len(text))


def _expect(fields: tuple[Any, ...]) -> tuple[Any, ...]:
    """What ``get`` returns for ``fields`` (a bytes field comes back padded)."""
    return tuple(_padded(f) if isinstance(f, bytes) else f for f in fields)


def _mix(a: bytes, b: bytes, take_b: list[bool], unit: int) -> bytes:
    out = bytearray(a)
    for k, use in enumerate(take_b):
        if use:
            out[k * unit : (k + 1) * unit] = b[k * unit : (k + 1) * unit]
    return bytes(out)


def _drain_lap(ring: Ring, make: Any) -> None:
    for i in range(ring.cap):
        assert ring.put(*make(i))
        assert ring.get() == _expect(make(i))


# ---------------------------------------------------------------- the check itself


@settings(max_examples=200, deadline=None)
@given(body=st.binary(min_size=8, max_size=200))
def test_a_slot_whose_check_matches_its_record_has_the_constant_crc(body: bytes) -> None:
    slot = body + SLOT_CHECK.pack(zlib.crc32(body))
    assert zlib.crc32(slot) == SLOT_RESIDUE
    # and one flipped bit anywhere (record or check) breaks it
    for bit in (0, 8 * len(body) - 1, 8 * len(body) + 5):
        bad = bytearray(slot)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert zlib.crc32(bytes(bad)) != SLOT_RESIDUE


def test_slots_are_8_byte_aligned_in_the_real_shared_block() -> None:
    """head/tail and every slot are aligned 8-byte cells (single-copy atomic stores)."""
    layout = Layout(3, 6)
    shm = SharedBlock.create(layout.size, "test")
    try:
        anchor = ctypes.c_char.from_buffer(shm.buf)
        address = ctypes.addressof(anchor)
        del anchor  # its export of the buffer ends
        shared = Shared(shm, layout)
        try:
            for ring in (*shared.segs, shared.stops, shared.events):
                assert (address + ring.base - 16) % 8 == 0
                assert (address + ring.base) % 8 == 0 and ring.slot % 8 == 0
            assert layout.size >= layout.event_ring + ring_size(EVENT_RECORD, shared.events.cap)
        finally:
            shared.release()
    finally:
        shm.close()
    with pytest.raises(ValueError, match="not 8-byte aligned"):
        Ring(memoryview(bytearray(4096)), 4, STOP_RECORD, 4)


# ---------------------------------------------------------------- what a reordering CPU shows


def test_new_head_and_sequence_over_an_old_payload_is_not_taken_until_complete() -> None:
    ring = scratch_ring(SEG_RECORD, 4)
    _drain_lap(ring, _seg)  # the slots now hold lap 0; the next record (4) reuses slot 0
    at = slot_offset(ring, 4)
    old = bytes(ring.buf[at : at + ring.slot])
    new = slot_bytes(ring, 4, _seg(41))
    seq_end, check_at = 8, SEG_RECORD.size

    show_slot(ring, 4, old)  # only the head is new
    assert ring.pending() and ring.get() is None
    show_slot(ring, 4, new[:seq_end] + old[seq_end:])  # head and sequence number new
    assert ring.get() is None
    show_slot(ring, 4, new[:check_at] + old[check_at:])  # the whole record new, the check old
    assert ring.get() is None
    show_slot(ring, 4, old[:check_at] + new[check_at:])  # the check new, the payload old
    assert ring.get() is None
    assert ring.cells[1] == 4 and ring.retries == 4  # nothing taken, nothing dropped
    show_slot(ring, 4, new)
    assert ring.get() == _seg(41)
    assert ring.cells[1] == 5 and not ring.pending()


def test_every_word_mix_of_the_old_and_the_new_segment_is_taken_only_when_whole() -> None:
    """All 2^9 mixes of the 9 eight-byte words of a segment slot (aligned 8-byte stores
    become visible in any order): only the complete new record is taken."""
    ring = scratch_ring(SEG_RECORD, 4)
    _drain_lap(ring, _seg)
    at = slot_offset(ring, 4)
    old = bytes(ring.buf[at : at + ring.slot])
    new = slot_bytes(ring, 4, _seg(41))
    words = ring.slot // 8
    taken = 0
    for mask in range(1 << words):
        seen = _mix(old, new, [bool(mask >> k & 1) for k in range(words)], 8)
        show_slot(ring, 4, seen)
        got = ring.get()
        if seen == new:
            assert got == _seg(41), f"mask {mask:#x}"
            taken += 1
            ring.cells[1] = 4  # read it again with the next mix
        else:
            assert got is None, f"mask {mask:#x}: a torn record was taken: {got}"
            assert ring.cells[1] == 4
    assert taken == 1


@settings(max_examples=300, deadline=None)
@given(bits=st.binary(min_size=25, max_size=25), lap=st.integers(1, 50))
def test_any_byte_mix_of_an_event_slot_with_its_text_is_taken_only_when_whole(
    bits: bytes, lap: int
) -> None:
    """struct packs standard-size fields byte by byte and the text with memcpy: a weakly
    ordered CPU may show any byte mix of the previous lap's record and the new one (``bits``:
    one bit a byte of the slot, set: the byte is already the new record's)."""
    mask = [bool(bits[k // 8] >> (k % 8) & 1) for k in range(200)]
    ring = scratch_ring(EVENT_RECORD, 2)
    assert ring.slot == 200
    for i in range(2 * lap):
        assert ring.put(*_event(i))
        assert ring.get() == _expect(_event(i))
    index = 2 * lap
    at = slot_offset(ring, index)
    old = bytes(ring.buf[at : at + ring.slot])
    new = slot_bytes(ring, index, _event(index, b"step timing lost (step 2417 us late)"))
    seen = _mix(old, new, mask, 1)
    show_slot(ring, index, seen)
    got = ring.get()
    if seen == new:
        assert got == _expect(_event(index, b"step timing lost (step 2417 us late)"))
    else:
        assert got is None and ring.cells[1] == index
        show_slot(ring, index, new)
        assert ring.get() == _expect(_event(index, b"step timing lost (step 2417 us late)"))


def test_a_slot_overwritten_by_the_next_lap_while_being_read_is_not_taken() -> None:
    """If the producer overwrote the slot during the consumer's copy (what the tail's
    control dependency prevents), the copy mixes record k and record k + capacity: it is
    taken only if it is record k, whole."""
    ring = scratch_ring(STOP_RECORD, 2)
    assert ring.put(1, 11, -1) and ring.put(2, 22, 7)  # records 0 and 1: full
    at = slot_offset(ring, 0)
    current = bytes(ring.buf[at : at + ring.slot])
    next_lap = slot_bytes(ring, 2, (3, 33, 5))
    words = ring.slot // 8
    for mask in range(1, 1 << words):
        seen = _mix(current, next_lap, [bool(mask >> k & 1) for k in range(words)], 8)
        ring.buf[at : at + ring.slot] = seen
        assert ring.get() is None, f"mask {mask:#x}"
        assert ring.cells[1] == 0
        assert not ring.put(9, 99, -1)  # still full: the producer does not touch the slot
    ring.buf[at : at + ring.slot] = current
    assert ring.get() == (1, 11, -1) and ring.get() == (2, 22, 7) and ring.get() is None


def test_a_rejected_record_keeps_its_slot_from_the_producer() -> None:
    ring = scratch_ring(SEG_RECORD, 4)
    for i in range(4):
        assert ring.put(*_seg(i))
    at = slot_offset(ring, 0)
    whole = bytes(ring.buf[at : at + ring.slot])
    ring.buf[at + 8 : at + 16] = bytes(8)  # record 0 not visible yet beyond its seq
    for _ in range(3):
        assert ring.get() is None
        assert ring.free() == 0 and not ring.put(*_seg(99))
    ring.buf[at : at + ring.slot] = whole
    assert [ring.get() for _ in range(4)] == [_seg(i) for i in range(4)]


@settings(max_examples=100, deadline=None)
@given(garbage=st.binary(min_size=72, max_size=72))
def test_garbage_in_a_slot_is_never_taken_and_never_raises(garbage: bytes) -> None:
    ring = scratch_ring(SEG_RECORD, 4)
    show_slot(ring, 0, garbage)
    assert ring.get() is None and ring.cells[1] == 0


# ---------------------------------------------------------------- plain ring behaviour


def test_a_full_ring_refuses_and_takes_again_after_a_get() -> None:
    ring = scratch_ring(SEG_RECORD, 8)
    assert ring.free() == 8 and not ring.pending() and ring.get() is None
    for i in range(8):
        assert ring.put(*_seg(i)), i
    assert ring.free() == 0 and not ring.put(*_seg(8))
    assert ring.get() == _seg(0)
    assert ring.free() == 1 and ring.put(*_seg(8)) and not ring.put(*_seg(9))
    got = []
    while (rec := ring.get()) is not None:
        got.append(rec)
    assert got == [_seg(i) for i in range(1, 9)]
    assert ring.free() == 8 and not ring.pending()
    # many laps, every record in order, whatever the fill level
    rng = random.Random(7)
    sent = received = 9
    for _ in range(2000):
        for _ in range(rng.randint(0, 9)):
            if ring.put(*_seg(sent)):
                sent += 1
        for _ in range(rng.randint(0, 9)):
            rec = ring.get()
            if rec is None:
                break
            assert rec == _seg(received)
            received += 1
        assert ring.free() == 8 - (sent - received)
    assert sent > 5000 and ring.retries == 0


def test_the_event_record_carries_its_text() -> None:
    ring = scratch_ring(EVENT_RECORD, 4)
    long = bytes(range(32, 127)) + b"x" * 25
    assert len(long) == TEXT
    for text in (b"", b"step timing lost (step 2417 us late)", long):
        assert ring.put(*_event(3, text))
        got = ring.get()
        assert got is not None and got == _expect(_event(3, text))
        assert got[-1].rstrip(b"\0") == text
    # a text half written is not taken
    index = ring.cells[0]
    at = slot_offset(ring, index)
    old = bytes(ring.buf[at : at + ring.slot])
    new = slot_bytes(ring, index, _event(4, long))
    text_at = EVENT_RECORD.size - TEXT
    show_slot(ring, index, new[: text_at + 60] + old[text_at + 60 :])
    assert ring.get() is None
    show_slot(ring, index, new)
    assert ring.get() == _expect(_event(4, long))


def test_a_stop_record_with_another_field_needs_no_ring_change() -> None:
    """The check is generic over the record's struct (the stop record may grow)."""
    grown = struct.Struct("<qqqq")
    ring = scratch_ring(grown, 4)
    assert ring.put(1, 2, 3) and ring.get() == (1, 2, 3)


# ---------------------------------------------------------------- two real processes


def _echo_child(name: str, count: int, seed: int, deadline: float) -> None:
    """Take segment records from ring A, give each back as an event record on ring B."""
    shm = shared_memory.SharedMemory(name=name)
    assert shm.buf is not None
    a = Ring(shm.buf, 0, SEG_RECORD, 16)
    b = Ring(shm.buf, ring_size(SEG_RECORD, 16), EVENT_RECORD, 8)
    rng = random.Random(seed + 1)
    held: tuple[Any, ...] | None = None
    done = 0
    try:
        while done < count and time.monotonic() < deadline:
            if held is None:
                rec = a.get()
                if rec is None:
                    if rng.random() < 0.2:
                        os.sched_yield()
                    continue
                held = rec
            i = (held[0] - 10**9) // 7919
            if b.put(*_event(i)):
                done += 1
                held = None
            elif rng.random() < 0.5:
                os.sched_yield()
            if rng.random() < 0.001:
                time.sleep(rng.random() * 0.002)  # a preempted consumer
    finally:
        a.release()
        b.release()
        shm.close()


@pytest.mark.parametrize(
    "count", [10_000, pytest.param(20_000, marks=pytest.mark.slow)], ids=["10k", "20k"]
)
def test_no_record_is_lost_or_duplicated_between_two_processes(count: int) -> None:
    """A randomised run of ``count`` records there and back. make test runs 10,000 (a few
    thousand laps of either ring, many full rings); make test-slow another 20,000 on a seed of
    its own (the 30,000 this test once ran in make test, in two parts)."""
    seed = int.from_bytes(os.urandom(4), "little")
    size = ring_size(SEG_RECORD, 16) + ring_size(EVENT_RECORD, 8)
    shm = shared_memory.SharedMemory(create=True, size=size)
    assert shm.buf is not None
    shm.buf[:size] = bytes(size)
    a = Ring(shm.buf, 0, SEG_RECORD, 16)
    b = Ring(shm.buf, ring_size(SEG_RECORD, 16), EVENT_RECORD, 8)
    ctx = multiprocessing.get_context("spawn")
    deadline = time.monotonic() + DEADLINE_S
    child = ctx.Process(target=_echo_child, args=(shm.name, count, seed, deadline), daemon=True)
    rng = random.Random(seed)
    sent = received = 0
    full = 0
    try:
        child.start()
        while received < count:
            if time.monotonic() > deadline:
                pytest.fail(
                    f"seed {seed}: only {received} of {count} records came back "
                    f"within {DEADLINE_S:.0f} s ({sent} sent, child alive: "
                    f"{child.is_alive()}, exit code {child.exitcode})"
                )
            for _ in range(rng.randint(1, 24)):  # bursts larger than the ring
                if sent == count:
                    break
                if not a.put(*_seg(sent)):
                    full += 1
                    break
                sent += 1
            for _ in range(rng.randint(0, 12)):
                rec = b.get()
                if rec is None:
                    break
                assert rec == _expect(_event(received)), f"seed {seed}: record {received}"
                received += 1
            if rng.random() < 0.001:
                time.sleep(rng.random() * 0.002)  # a preempted producer
            if not child.is_alive() and not b.pending():
                pytest.fail(
                    f"seed {seed}: the child ended (exit code {child.exitcode}) "
                    f"with {received} of {count} records back"
                )
        child.join(DEADLINE_S)
        assert child.exitcode == 0
        assert b.get() is None and not a.pending()
        assert full > 0  # the producer did run into a full ring
    finally:
        if child.is_alive():
            child.kill()
            child.join(5)
        a.release()
        b.release()
        shm.close()
        shm.unlink()


# ---------------------------------------------------------------- retries, counted and reported


def test_a_consumer_counts_each_read_of_a_torn_or_stale_record_as_a_retry() -> None:
    ring = scratch_ring(SEG_RECORD, 4)
    _drain_lap(ring, _seg)  # slot 0 holds record 0 of the previous lap
    assert ring.retries == 0
    at = slot_offset(ring, 4)
    old = bytes(ring.buf[at : at + ring.slot])
    new = slot_bytes(ring, 4, _seg(41))
    show_slot(ring, 4, old)  # announced, the slot still the previous lap's: stale
    assert ring.get() is None and ring.retries == 1
    show_slot(ring, 4, new[:8] + old[8:])  # its sequence number new, the rest old: torn
    assert ring.get() is None and ring.get() is None and ring.retries == 3
    show_slot(ring, 4, new)
    assert ring.get() == _seg(41) and ring.retries == 3  # taken whole, once: no retry
    assert ring.get() is None and ring.retries == 3  # an empty ring is not a retry
    assert ring.cells[2] == 3  # a cell of the shared block: the other process reads it


def test_the_shared_block_sums_retries_by_direction() -> None:
    layout = Layout(2, 4)
    shm = SharedBlock.create(layout.size, "test")  # zero-filled
    try:
        shared = Shared(shm, layout)
        try:
            for ring, torn in ((shared.segs[1], 2), (shared.stops, 1), (shared.events, 4)):
                show_slot(ring, 0, bytes(ring.slot))  # announced, nothing written yet
                for _ in range(torn):
                    assert ring.get() is None
            assert shared.ring_retries() == {"ring_retries_segments": 3, "ring_retries_reports": 4}
        finally:
            shared.release()
    finally:
        shm.close()
