"""Tests for motorctl.protocol.framing."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from motorctl.protocol.framing import Framer

FRAME = 10


def reference(reads: list[tuple[bytes, float]], gap_s: float) -> tuple[list[bytes], int, int]:
    """Byte-at-a-time model of §2: (frames, partial frames discarded, bytes left pending)."""
    frames: list[bytes] = []
    partial: list[int] = []
    last = 0.0
    discarded = 0
    for data, now in reads:
        for byte in data:
            if partial and gap_s > 0 and now > last + gap_s:
                partial = []
                discarded += 1
            partial.append(byte)
            last = now
            if len(partial) == FRAME:
                frames.append(bytes(partial))
                partial = []
    return frames, discarded, len(partial)


def split(stream: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(stream) + 1) for c in cuts})
    bounds = [0, *points, len(stream)]
    return [stream[a:b] for a, b in itertools.pairwise(bounds)]


@st.composite
def stream_and_cuts(draw: st.DrawFn) -> tuple[bytes, list[int]]:
    stream = draw(st.binary(max_size=120))
    cuts = draw(st.lists(st.integers(0, 10_000), max_size=30))
    return stream, cuts


@given(stream_and_cuts(), st.sampled_from([0.0, 0.01, 10.0]))
def test_split_at_same_time_equals_whole(sc: tuple[bytes, list[int]], gap_s: float) -> None:
    stream, cuts = sc
    whole = Framer(gap_s)
    expected = whole.feed(stream, 5.0)
    assert expected == [stream[i : i + FRAME] for i in range(0, len(stream) - FRAME + 1, FRAME)]
    pieces = Framer(gap_s)
    got: list[bytes] = []
    for piece in split(stream, cuts):
        got += pieces.feed(piece, 5.0)
    assert got == expected
    assert pieces.pending == whole.pending == len(stream) % FRAME
    assert pieces.discarded == whole.discarded == 0


@given(stream_and_cuts(), st.lists(st.integers(0, 10), min_size=31, max_size=31))
def test_split_with_gaps_within_limit_equals_whole(
    sc: tuple[bytes, list[int]], steps: list[int]
) -> None:
    # Integer timestamps are exact floats; a step equal to gap_s is still within the limit.
    stream, cuts = sc
    gap_s = 10.0
    expected = Framer(gap_s).feed(stream, 0.0)
    framer = Framer(gap_s)
    got: list[bytes] = []
    now = 0.0
    for piece, step in zip(split(stream, cuts), steps, strict=False):
        now += step
        got += framer.feed(piece, now)
    assert got == expected
    assert framer.discarded == 0
    assert framer.pending == len(stream) % FRAME


@given(
    st.lists(
        st.tuples(st.binary(max_size=25), st.floats(-1e6, 1e6, allow_nan=False)),
        max_size=40,
    ),
    st.sampled_from([-1.0, 0.0, 0.001, 0.01, 1.0, 100.0]),
)
def test_random_reads_match_reference(reads: list[tuple[bytes, float]], gap_s: float) -> None:
    framer = Framer(gap_s)
    got: list[bytes] = []
    for data, now in reads:
        got += framer.feed(data, now)
        assert 0 <= framer.pending < FRAME
        deadline = framer.deadline()
        if framer.pending and gap_s > 0:
            assert deadline == now + gap_s or not data
        else:
            assert deadline is None
    frames, discarded, pending = reference(reads, gap_s)
    assert got == frames
    assert framer.discarded == discarded
    assert framer.pending == pending
    assert all(len(f) == FRAME for f in got)


@given(
    st.lists(
        st.tuples(
            st.sampled_from(["feed", "expire"]),
            st.binary(max_size=25),
            st.floats(0, 1e3, allow_nan=False),
        ),
        max_size=40,
    )
)
def test_random_feed_and_expire_never_raise(ops: list[tuple[str, bytes, float]]) -> None:
    framer = Framer(0.5)
    total = 0
    emitted = 0
    for op, data, now in ops:
        if op == "feed":
            total += len(data)
            emitted += FRAME * len(framer.feed(data, now))
        else:
            before = framer.pending
            dropped = framer.expire(now)
            assert dropped == (before > 0 and framer.pending == 0)
        assert 0 <= framer.pending < FRAME
    # Conservation: every byte is in a frame, pending, or in a discarded partial frame.
    assert emitted + framer.pending <= total
    assert total - emitted - framer.pending <= framer.discarded * (FRAME - 1)


def test_gap_discards_exactly_the_partial_frame() -> None:
    framer = Framer(0.010)
    assert framer.feed(b"\x01\x02\x03\x04", 1.000) == []
    assert framer.pending == 4
    frame = bytes(range(20, 30))
    assert framer.feed(frame + b"\xaa", 1.020) == [frame]
    assert framer.discarded == 1
    assert framer.pending == 1


def test_gap_discard_then_new_frame_across_reads() -> None:
    framer = Framer(0.010)
    framer.feed(bytes(7), 0.0)
    assert framer.feed(b"\x01\x02\x03", 0.5) == []  # starts a new frame, not completes the old
    assert framer.discarded == 1
    assert framer.pending == 3
    assert framer.feed(bytes(range(4, 11)), 0.505) == [bytes(range(1, 11))]
    assert framer.pending == 0
    assert framer.discarded == 1


def test_gap_measured_from_last_byte_not_first() -> None:
    framer = Framer(0.010)
    now = 0.0
    frames: list[bytes] = []
    for i in range(10):
        frames += framer.feed(bytes([i]), now)
        now += 0.008  # each gap below the limit, total span well above it
    assert frames == [bytes(range(10))]
    assert framer.discarded == 0


def test_gap_equal_to_limit_keeps_bytes() -> None:
    framer = Framer(2.0)
    framer.feed(b"\x01", 1.0)
    assert framer.feed(b"\x02", 3.0) == []
    assert framer.pending == 2
    assert framer.discarded == 0
    framer.feed(b"\x03", 5.5)
    assert framer.pending == 1
    assert framer.discarded == 1


def test_no_discard_without_pending_bytes() -> None:
    framer = Framer(0.010)
    assert framer.feed(bytes(10), 0.0) == [bytes(10)]
    assert framer.feed(bytes(10), 100.0) == [bytes(10)]
    assert framer.discarded == 0
    assert framer.expire(1000.0) is False


@pytest.mark.parametrize("gap_s", [0.0, -1.0])
def test_gap_off_never_discards(gap_s: float) -> None:
    framer = Framer(gap_s)
    framer.feed(b"\x01\x02", 0.0)
    assert framer.deadline() is None
    assert framer.expire(1e9) is False
    assert framer.feed(bytes(range(3, 11)), 1e9) == [bytes(range(1, 11))]
    assert framer.discarded == 0


def test_expire_and_deadline() -> None:
    framer = Framer(0.010)
    assert framer.deadline() is None
    assert framer.expire(5.0) is False
    framer.feed(b"\x01\x02\x03", 1.0)
    assert framer.deadline() == pytest.approx(1.010)
    framer.feed(b"\x04", 1.005)
    deadline = framer.deadline()
    assert deadline == pytest.approx(1.015)
    assert deadline is not None
    assert framer.expire(1.008) is False
    assert framer.expire(deadline) is False  # strict: exactly at the deadline is still in time
    assert framer.pending == 4
    assert framer.expire(1.020) is True
    assert framer.pending == 0
    assert framer.discarded == 1
    assert framer.deadline() is None
    assert framer.expire(2.0) is False
    assert framer.discarded == 1
    # After an expiry the next bytes start a fresh frame.
    assert framer.feed(bytes(range(10)), 3.0) == [bytes(range(10))]


def test_empty_feed_changes_nothing() -> None:
    framer = Framer(0.010)
    framer.feed(b"\x01", 0.0)
    assert framer.feed(b"", 10.0) == []
    assert framer.pending == 1
    assert framer.deadline() == pytest.approx(0.010)
