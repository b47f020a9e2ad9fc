"""Tests for motorctl.protocol.framing: frames from bytes, the gap judged from watched silence."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from motorctl.protocol.framing import Framer

FRAME = 10


def reference(events: list[tuple[bytes, int]], gap: int) -> tuple[list[bytes], int, int]:
    """Byte-at-a-time model of §2 with integer silences: (frames, discards, bytes pending).

    Each event is bytes read, then a silence watched after them; a partial frame whose
    silence since its last byte adds up to more than ``gap`` is dropped."""
    frames: list[bytes] = []
    partial: list[int] = []
    silence = 0
    discarded = 0
    for data, quiet in events:
        for byte in data:
            silence = 0
            partial.append(byte)
            if len(partial) == FRAME:
                frames.append(bytes(partial))
                partial = []
        if partial and gap > 0:
            silence += quiet
            if silence > gap:
                partial = []
                silence = 0
                discarded += 1
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
def test_split_reads_equal_whole(sc: tuple[bytes, list[int]], gap_s: float) -> None:
    # However late the pieces are read, with no silence watched between them they are
    # contiguous: a backlog in the kernel's buffer is never a gap.
    stream, cuts = sc
    whole = Framer(gap_s)
    expected = whole.feed(stream)
    assert expected == [stream[i : i + FRAME] for i in range(0, len(stream) - FRAME + 1, FRAME)]
    pieces = Framer(gap_s)
    got: list[bytes] = []
    for piece in split(stream, cuts):
        got += pieces.feed(piece)
    assert got == expected
    assert pieces.pending == whole.pending == len(stream) % FRAME
    assert pieces.discarded == whole.discarded == 0


@given(stream_and_cuts(), st.lists(st.integers(0, 10), min_size=31, max_size=31))
def test_silences_within_limit_equal_whole(sc: tuple[bytes, list[int]], quiets: list[int]) -> None:
    # Integer silences are exact floats; a silence equal to gap_s is still within the limit.
    stream, cuts = sc
    expected = Framer(10.0).feed(stream)
    framer = Framer(10.0)
    got: list[bytes] = []
    pieces = [p for p in split(stream, cuts) if p]
    for piece, quiet in zip(pieces, quiets, strict=False):
        got += framer.feed(piece)
        assert framer.idle(quiet) is False
    assert got == expected
    assert framer.discarded == 0
    assert framer.pending == len(stream) % FRAME


@given(
    st.lists(st.tuples(st.binary(max_size=25), st.integers(0, 30)), max_size=40),
    st.sampled_from([-1, 0, 1, 5, 10, 100]),
)
def test_random_reads_and_silences_match_reference(
    events: list[tuple[bytes, int]], gap: int
) -> None:
    framer = Framer(float(gap))
    got: list[bytes] = []
    for data, quiet in events:
        got += framer.feed(data)
        assert 0 <= framer.pending < FRAME
        left = framer.gap_left()
        if framer.pending and gap > 0:
            assert left is not None and 0 <= left <= gap
        else:
            assert left is None
        before = framer.pending
        dropped = framer.idle(float(quiet))
        assert dropped == (before > 0 and framer.pending == 0)
    frames, discarded, pending = reference(events, gap)
    assert got == frames
    assert framer.discarded == discarded
    assert framer.pending == pending
    assert all(len(f) == FRAME for f in got)


def test_silence_discards_exactly_the_partial_frame() -> None:
    framer = Framer(0.010)
    assert framer.feed(b"\x01\x02\x03\x04") == []
    assert framer.idle(0.020) is True
    frame = bytes(range(20, 30))
    assert framer.feed(frame + b"\xaa") == [frame]
    assert framer.discarded == 1
    assert framer.pending == 1


def test_silence_adds_up_across_watches_and_restarts_with_each_byte() -> None:
    framer = Framer(0.010)
    framer.feed(b"\x01")
    for _ in range(3):
        assert framer.idle(0.003) is False  # 9 ms watched in three stretches
    assert framer.gap_left() == pytest.approx(0.001)
    framer.feed(b"\x02")  # a byte: the silence starts again
    assert framer.gap_left() == pytest.approx(0.010)
    assert framer.idle(0.008) is False
    assert framer.idle(0.003) is True
    assert framer.discarded == 1 and framer.pending == 0


def test_gap_measured_from_last_byte_not_first() -> None:
    framer = Framer(0.010)
    frames: list[bytes] = []
    for i in range(10):
        frames += framer.feed(bytes([i]))
        framer.idle(0.008)  # each gap below the limit, the total span well above it
    assert frames == [bytes(range(10))]
    assert framer.discarded == 0


def test_gap_equal_to_limit_keeps_bytes() -> None:
    framer = Framer(2.0)
    framer.feed(b"\x01")
    assert framer.idle(2.0) is False
    assert framer.gap_left() == 0.0
    assert framer.feed(b"\x02") == []
    assert framer.pending == 2
    assert framer.idle(2.5) is True
    framer.feed(b"\x03")
    assert framer.pending == 1
    assert framer.discarded == 1


def test_no_discard_without_pending_bytes() -> None:
    framer = Framer(0.010)
    assert framer.feed(bytes(10)) == [bytes(10)]
    assert framer.idle(100.0) is False
    assert framer.feed(bytes(10)) == [bytes(10)]
    assert framer.discarded == 0
    assert framer.gap_left() is None


@pytest.mark.parametrize("gap_s", [0.0, -1.0])
def test_gap_off_never_discards(gap_s: float) -> None:
    framer = Framer(gap_s)
    framer.feed(b"\x01\x02")
    assert framer.gap_left() is None
    assert framer.idle(1e9) is False
    assert framer.feed(bytes(range(3, 11))) == [bytes(range(1, 11))]
    assert framer.discarded == 0


def test_reset_drops_partial_without_counting_a_gap() -> None:
    framer = Framer(0.010)
    framer.feed(b"\x01\x02\x03")
    framer.idle(0.005)
    assert framer.reset() == 3
    assert framer.pending == 0 and framer.discarded == 0
    assert framer.reset() == 0
    assert framer.feed(bytes(range(10))) == [bytes(range(10))]
    assert framer.idle(0.0) is False


def test_empty_feed_changes_nothing() -> None:
    framer = Framer(0.010)
    framer.feed(b"\x01")
    framer.idle(0.004)
    assert framer.feed(b"") == []
    assert framer.pending == 1
    assert framer.gap_left() == pytest.approx(0.006)
