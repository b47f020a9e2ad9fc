"""The pure link session, without a PTY: framing by watched silence, held frames, WaitMoved.

The real dispatcher and motion engine run on a virtual clock behind it, so "the motor is
moving" and "the motor became idle" are the engine's own states, not a script.
"""

from __future__ import annotations

import random
import tempfile
from collections.abc import Sequence
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from motorctl.daemon.dispatcher import Wait
from motorctl.daemon.link.session import Ended, LinkSession
from motorctl.hal.backends.mock.world import world_of
from motorctl.protocol.codec import (
    Command,
    ErrorCode,
    GetAbsPos,
    GetPin,
    IsReady,
    Move,
    MoveTo,
    Response,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
    decode_response,
)
from tests.support.frames import OPTS, frame
from tests.support.sessions import GAP_S as GAP
from tests.support.sessions import SessionRig

E = ErrorCode

CONFIG = """
[[motors]]
name = "a"
[[motors]]
name = "b"
[[pins]]
number = 0
"""


@pytest.fixture
def w(tmp_path: Path) -> SessionRig:
    return SessionRig(tmp_path, CONFIG)


def codes(rs: Sequence[Response]) -> list[ErrorCode | None]:
    return [r.error_code for r in rs]


def corrupt(data: bytes, bit: int) -> bytes:
    out = bytearray(data)
    out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


# -- framing ---------------------------------------------------------------------------
def test_burst_of_5000_frames_in_one_read(w: SessionRig) -> None:
    cmds: list[Command] = [GetAbsPos(i % 2) if i % 3 else IsReady(i % 2) for i in range(5000)]
    w.send(*cmds)
    rs = w.responses()
    assert len(rs) == 5000 and all(r.ack for r in rs)
    assert w.session.counters["frames_good"] == 5000
    assert w.session.counters["gap_discards"] == 0


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=60), st.integers(0, 2**32))
def test_any_split_without_watched_silence_is_contiguous(sizes: list[int], seed: int) -> None:
    # However the stream is cut into reads, and however late each is read (the timestamps
    # jump by seconds), frames come out whole: only watched silence is a gap.
    with tempfile.TemporaryDirectory() as tmp:
        check_split(sizes, seed, SessionRig(Path(tmp), CONFIG))


def check_split(sizes: list[int], seed: int, w: SessionRig) -> None:
    rng = random.Random(seed)
    cmds = [GetAbsPos(rng.randrange(2)) for _ in range(300)]
    stream = b"".join(frame(c) for c in cmds)
    pos = 0
    t = w.now
    for size in sizes:
        if pos >= len(stream):
            break
        t += rng.choice([0.0, 0.001, 5.0])
        w.session.receive(stream[pos : pos + size], t)
        w.session.idle(rng.uniform(0, GAP))  # watched silence within the limit
        pos += size
    w.session.receive(stream[pos:], t)
    rs = w.responses()
    assert len(rs) == 300 and all(r.ack for r in rs)
    assert w.session.counters["gap_discards"] == 0


def test_watched_silence_discards_partial_and_resyncs(w: SessionRig) -> None:
    good = frame(IsReady(0))
    w.session.receive(frame(MoveTo(0, True, 500, 0, 0, 0))[:6], w.now)
    w.session.idle(GAP / 2)
    w.session.idle(GAP / 2)  # exactly the gap: still kept
    assert w.session.framer.pending == 6
    w.session.idle(0.0001)  # more than the gap
    assert w.session.counters["gap_discards"] == 1
    w.session.receive(good, w.now)
    assert [r.as_bool for r in w.responses()] == [True]
    assert w.engine.motors[0].idle  # the MoveTo fragment was not executed


def test_bad_frames_answered_e1_and_not_executed(w: SessionRig) -> None:
    move = frame(MoveTo(0, True, 500, 0, 0, 0))
    pin = frame(SetPin(0, True))
    bad = [corrupt(move, b) for b in range(80)] + [corrupt(pin, b) for b in range(80)]
    w.session.receive(b"".join(bad), w.now)
    rs = w.responses()
    # An 8-bit CRC catches every single-bit error; padding and unknown codes are E1 as well.
    assert codes(rs) == [E.INVALID_COMMAND] * 160
    assert w.engine.motors[0].idle and w.engine.motors[0].position == 0
    assert world_of(w.daemon.hw).pins[0].read() is False
    c = w.session.counters
    assert c["checksum_errors"] == 160 and c["sent_E1"] == 160 and c["frames_good"] == 0


def test_unknown_code_and_bad_padding(w: SessionRig) -> None:
    from motorctl.protocol.crc import SMBUS

    unknown = bytes([0x0F]) + bytes(8)
    padded = bytes([0x03, 0x00, 0x01]) + bytes(6)
    w.session.receive(
        unknown + bytes([SMBUS.compute(unknown)]) + padded + bytes([SMBUS.compute(padded)]), w.now
    )
    assert codes(w.responses()) == [E.INVALID_COMMAND] * 2
    assert w.session.counters["unknown_errors"] == 1
    assert w.session.counters["padding_errors"] == 1


# -- remembered frames and answers ----------------------------------------------------------
def test_a_repeated_frame_is_answered_from_the_state_of_the_moment(w: SessionRig) -> None:
    # The session remembers what a frame decodes to and how an answer encodes, never the
    # answer itself: the same IsReady/GetAbsPos bytes answer differently as the motor moves.
    ready, where = frame(IsReady(0)), frame(GetAbsPos(0))
    w.session.receive(ready + where, w.now)
    w.send(MoveTo(0, True, 300, 0, 0, 0))
    w.session.receive(ready, w.now)
    before = w.responses()
    assert [r.as_bool for r in before[:1]] == [True] and before[1].as_position == 0
    assert before[2].ack and before[3].ack and before[3].as_bool is False
    assert ready in w.session._decoded  # the second IsReady took the remembered path
    w.run(5.0)
    w.session.receive(ready + where, w.now)
    after = w.responses()
    assert after[0].as_bool is True and after[1].as_position == 300


def test_remembered_frames_and_answers_stay_bounded(w: SessionRig) -> None:
    from motorctl.daemon.link.session import CACHE_LIMIT

    queries: list[IsReady | GetAbsPos | GetPin] = [IsReady(m) for m in range(256)]
    queries += [GetAbsPos(m) for m in range(256)] + [GetPin(p) for p in range(256)]
    for _ in range(2):
        w.send(*queries)
        rs = w.responses()
        assert len(rs) == len(queries)
        for cmd, r in zip(queries, rs, strict=True):
            known = cmd.pin == 0 if isinstance(cmd, GetPin) else cmd.motor < 2
            assert r.ack is known and (known or r.error_code is E.INVALID_ADDRESS), (cmd, r)
    assert 0 < len(w.session._decoded) <= CACHE_LIMIT
    positions = range(-3 * CACHE_LIMIT, 0, 3)  # as many distinct answers
    for target in positions:
        w.engine.motors[1].set_position(target)  # as homing or a restored state does
        w.send(GetAbsPos(1))
        assert w.responses()[0].as_position == target
    assert 0 < len(w.session._encoded) <= CACHE_LIMIT


def test_a_bad_frame_is_checked_and_counted_each_time_it_comes(w: SessionRig) -> None:
    bad = corrupt(frame(IsReady(0)), 3)
    for n in range(1, 4):
        w.session.receive(bad, w.now)
        assert codes(w.responses()) == [E.INVALID_COMMAND]
        assert w.session.counters["checksum_errors"] == n
    assert bad not in w.session._decoded


_POOL: list[Command] = [
    IsReady(0),
    IsReady(1),
    IsReady(5),
    GetAbsPos(0),
    GetAbsPos(1),
    GetAbsPos(7),
    GetPin(0),
    GetPin(3),
    SetPin(0, True),
    SetPin(0, False),
    MoveTo(0, True, 40, 0, 0, 0),
    MoveTo(0, True, -25, 0, 0, 0),
    MoveTo(1, True, 10, 0, 0, 0),
    StopMove(0, False),
    StopMove(1, True),
    WaitMoved(0, 0),
    WaitMoved(0, 30),
    WaitMoved(1, 200),
]

#: reads for the two worlds to take: a frame of _POOL (-1: a stray partial frame), a bit to
#: flip in it (negative: none), the time that passes after it
STEPS = st.lists(
    st.tuples(
        st.integers(-1, len(_POOL) - 1),
        st.integers(-240, 79),  # 1/4 bad
        st.sampled_from([0.0, 0.001, 0.02]),
    ),
    min_size=1,
    max_size=80,
)

#: a stray partial frame (STEPS' index -1): what follows it is misaligned
STRAY = b"\x01\x02\x03"


def step_frame(index: int, bad_bit: int) -> bytes:
    """The frame of STEPS' ``index`` in _POOL, with ``bad_bit`` flipped (negative: none)."""
    data = frame(_POOL[index])
    return corrupt(data, bad_bit) if bad_bit >= 0 else data


@settings(max_examples=60, deadline=None)
# held behind a WaitMoved (the motor is on its way), then behind a stray partial frame
@example(
    [
        (0, -1, 0.0),
        (10, -1, 0.0),
        (16, -1, 0.0),
        (0, -1, 0.0),
        (3, -1, 0.05),
        (-1, -1, 0.0),
        (0, -1, 0.0),
        (0, -1, 0.0),
        (0, 5, 0.02),
        (3, -1, 0.0),
    ]
)
@given(STEPS)
def test_whole_frames_read_alone_answer_and_count_as_split_ones(
    steps: list[tuple[int, int, float]],
) -> None:
    # A whole frame read alone, one the session has seen, takes a shorter path (no frame
    # partial, nothing held). The same frames read in two halves never do. Both worlds
    # must give the same answers and counts at every step, WaitMoved holding included.
    with tempfile.TemporaryDirectory() as ta, tempfile.TemporaryDirectory() as tb:
        whole, split = SessionRig(Path(ta), CONFIG), SessionRig(Path(tb), CONFIG)
        for index, bad_bit, dt in steps:
            if index < 0:  # a stray partial frame: what follows is misaligned in both
                whole.session.receive(STRAY, whole.now)
                split.session.receive(STRAY, split.now)
                continue
            data = step_frame(index, bad_bit)
            whole.session.receive(data, whole.now)
            split.session.receive(data[:4], split.now)
            split.session.receive(data[4:], split.now)
            assert whole.session.take_output() == split.session.take_output()
            whole.run(dt)
            split.run(dt)
            for w in (whole, split):
                w.session.idle(dt)  # 20 ms of watched silence drops a partial frame
            assert whole.session.take_output() == split.session.take_output()
            assert whole.session.counters == split.session.counters
            assert whole.session.held == split.session.held
        assert [m.position for m in whole.engine.motors] == [
            m.position for m in split.engine.motors
        ]


def taken(rig: SessionRig, data: bytes) -> bytes:
    """``data`` read as the link reads it: :meth:`LinkSession.answer` for the usual read,
    :meth:`LinkSession.receive` and :meth:`LinkSession.take_output` for any other."""
    out = rig.session.answer(data, rig.now)
    if out is None:
        rig.session.receive(data, rig.now)
        return rig.session.take_output()
    return out


@settings(max_examples=60, deadline=None)
@example([(0, -1, 0.0), (0, -1, 0.0), (10, -1, 0.0), (0, -1, 0.0), (0, -1, 0.0)])
@example([(0, -1, 0.0), (-1, -1, 0.0), (0, -1, 0.0), (0, -1, 0.0), (0, -1, 0.0)])
@example([(1, -1, 0.0), (1, 3, 0.0), (1, 3, 0.0), (16, -1, 0.0), (16, -1, 0.0)])
@given(STEPS)
def test_a_read_answered_at_once_is_a_read_received_and_taken(
    steps: list[tuple[int, int, float]],
) -> None:
    """The link hands each read to :meth:`LinkSession.answer` first: the usual read (a whole
    frame seen before, no WaitMoved, nothing partial or held) is answered there, any other
    is left untouched for :meth:`LinkSession.receive`. Both worlds give the same answers,
    counts, outputs and last frames at every step, WaitMoved holding included."""
    with tempfile.TemporaryDirectory() as ta, tempfile.TemporaryDirectory() as tb:
        fast, plain = SessionRig(Path(ta), CONFIG), SessionRig(Path(tb), CONFIG)
        for index, bad_bit, dt in steps:
            if index < 0:  # a stray partial frame: never answered at once, nor what follows
                assert fast.session.answer(STRAY, fast.now) is None
                fast.session.receive(STRAY, fast.now)
                plain.session.receive(STRAY, plain.now)
                continue
            data = step_frame(index, bad_bit)
            out = taken(fast, data)
            plain.session.receive(data, plain.now)
            assert out == plain.session.take_output()
            for w in (fast, plain):
                w.run(dt)
                w.session.idle(dt)
            assert fast.session.take_output() == plain.session.take_output()
            assert fast.session.counters == plain.session.counters
            assert fast.session.outputs == plain.session.outputs
            assert fast.session.held == plain.session.held
            assert fast.session.recent() == plain.session.recent()
        assert [m.position for m in fast.engine.motors] == [m.position for m in plain.engine.motors]


def test_only_the_usual_read_is_answered_at_once(w: SessionRig) -> None:
    """:meth:`LinkSession.answer`: a frame not seen before, a WaitMoved, a read while a
    WaitMoved holds, a partial frame: None, and nothing counted or run."""
    first = frame(GetAbsPos(0))
    assert w.session.answer(first, w.now) is None  # not seen before: the framer decodes it
    assert w.session.counters["bytes_in"] == 0 and w.session.outputs == 0
    assert taken(w, first) == taken(w, first)  # now seen: answered at once, the same
    assert w.session.outputs == 2 and w.session.counters["frames"] == 2
    w.send(MoveTo(0, True, 400, 250, 0, 0), WaitMoved(0, 10_000))
    assert w.session.waiting
    counters = w.session.counters.copy()
    assert w.session.answer(first, w.now) is None  # held behind the wait
    assert w.session.answer(frame(WaitMoved(0, 10_000)), w.now) is None
    assert w.session.counters == counters and w.session.held == 0
    w.run(5.0)
    assert [r.ack for r in w.responses()] == [True, True]  # the MoveTo's, the wait's
    w.session.receive(first[:3], w.now)
    assert w.session.answer(first, w.now) is None  # a partial frame before it
    assert w.session.counters["frames"] == 4


# -- WaitMoved ------------------------------------------------------------------------------
def test_wait_idle_motor_answers_at_once(w: SessionRig) -> None:
    w.send(WaitMoved(0, 100))
    assert codes(w.responses()) == [None]
    assert not w.session.waiting


def test_wait_held_frames_answered_after_in_order(w: SessionRig) -> None:
    w.send(MoveTo(0, True, 200, 0, 0, 0))
    w.send(WaitMoved(0, 5000), IsReady(1), GetAbsPos(0), MoveTo(1, True, 50, 0, 0, 0))
    assert codes(w.responses()) == [None]  # only the MoveTo before the wait
    assert w.session.waiting and w.session.held == 3
    assert w.engine.motors[1].idle  # held frames are not executed yet
    w.run(10.0)
    rs = w.responses()
    assert [r.ack for r in rs] == [True] * 4
    assert rs[1].as_bool is True and rs[2].as_position == 200
    assert not w.engine.motors[1].idle  # the MoveTo ran after the wait


def test_bad_frame_while_wait_held_keeps_its_turn(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 5000))
    w.session.receive(corrupt(frame(StopMove(0, True)), 3) + frame(IsReady(1)), w.now)
    w.run(0.01)
    assert w.session.waiting  # the corrupted StopMove did not stop the motor
    w.send(StopMove(0, False))
    w.run(5.0)
    assert codes(w.responses())[1:] == [None, E.INVALID_COMMAND, None, None]


def test_wait_behind_wait_timeout_counts_from_take_up(w: SessionRig) -> None:
    w.send(MoveTo(0, True, 2000, 0, 0, 0))  # about 1.2 s at the defaults
    w.send(Move(1, True, 1, 0, 0))  # runs until stopped
    t0 = w.now
    w.send(WaitMoved(0, 10_000), WaitMoved(1, 500), GetAbsPos(1))
    assert len(w.responses()) == 2
    while w.session.wait is not None and w.session.wait.motor.index == 0:
        w.run(0.05)
        assert w.now - t0 < 5, "first WaitMoved never answered"
    t_take_up = w.now
    assert t_take_up - t0 > 0.5  # the second wait's TIMEOUT would be over if counted from arrival
    assert codes(w.responses()) == [None]
    wait = w.session.wait
    assert isinstance(wait, Wait) and wait.deadline == pytest.approx(t_take_up + 0.5)
    w.run(0.49)
    assert w.session.waiting
    w.run(0.02)
    rs = w.responses()
    assert codes(rs) == [E.MOTOR_NOT_READY, None]
    w.send(StopMove(1, True))


def test_held_overflow_e0_and_stop_never_refused(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), *[GetAbsPos(1)] * 18)
    assert w.session.counters["held_overflow"] == 2
    w.send(StopMove(0, True))  # buffer full: executed on arrival all the same
    assert not w.engine.motors[0].active
    w.send(IsReady(0))
    rs = w.responses()[1:]
    assert codes(rs) == [None] + [None] * 16 + [E.FULL_BUFFER] * 2 + [None, None]
    assert rs[-1].as_bool is True
    c = w.session.counters
    assert c["stops_while_held"] == 1 and c["sent_E0"] == 2


def test_a_bad_frame_takes_its_place_among_the_held_frames(w: SessionRig) -> None:
    # PROTOCOL.md §4: later frames are kept "up to 16; beyond that each gets E0"; only a
    # StopMove is exempt. A frame with a bad checksum is one of the 16: the SetPin behind
    # 4 + 1 bad + 1 + 10 frames is the 17th and is refused, not executed.
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 600), *[GetAbsPos(0)] * 4)
    w.session.receive(corrupt(frame(GetAbsPos(1)), 77), w.now)
    w.send(IsReady(77), *[GetAbsPos(0)] * 10, SetPin(0, True))
    assert w.session.held == 17
    assert w.session.counters["held_overflow"] == 1
    w.run(0.7)  # the WaitMoved times out (E3) and the kept frames run
    rs = codes(w.responses()[1:])
    assert rs == (
        [E.MOTOR_NOT_READY]
        + [None] * 4
        + [E.INVALID_COMMAND, E.INVALID_ADDRESS]
        + [None] * 10
        + [E.FULL_BUFFER]
    )
    assert world_of(w.daemon.hw).pins[0].read() is False  # the 17th frame never ran
    w.send(StopMove(0, True))


def test_a_bad_frame_beyond_the_held_frames_is_e1_and_frees_no_place(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), *[GetAbsPos(1)] * 15)
    bad = corrupt(frame(SetPin(0, True)), 5)
    w.session.receive(bad + bad, w.now)  # the 16th place, then none left: E1 comes before E0
    w.send(SetPin(0, True), StopMove(0, True), IsReady(0))
    rs = codes(w.responses()[1:])
    assert rs == [None] * 16 + [E.INVALID_COMMAND] * 2 + [E.FULL_BUFFER, None, None]
    assert world_of(w.daemon.hw).pins[0].read() is False
    c = w.session.counters
    assert c["held_overflow"] == 2 and c["sent_E1"] == 2 and c["sent_E0"] == 1
    assert c["checksum_errors"] == 2 and w.session._held_places == 0


def test_stop_for_unknown_motor_while_held_is_e2_in_turn(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), StopMove(7, True), IsReady(1))
    assert w.session.waiting
    w.send(StopMove(0, False))
    w.run(5.0)
    assert codes(w.responses()[1:]) == [None, E.INVALID_ADDRESS, None, None]


def test_stop_of_other_motor_while_held_keeps_wait(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0), Move(1, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), StopMove(1, True))
    assert w.session.waiting and not w.engine.motors[1].active  # executed on arrival
    w.send(StopMove(0, True))
    assert codes(w.responses()[2:]) == [None, None, None]


def test_wait_reports_fault_then_held_frames(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), IsReady(0), GetAbsPos(0))
    world_of(w.daemon.hw).inject_fault(0, "overtemperature")
    w.run(0.05)
    rs = w.responses()[1:]
    assert codes(rs) == [E.MOTOR_ERROR, E.MOTOR_ERROR, None]


def test_wait_timeout_then_wait_zero(w: SessionRig) -> None:
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 100))
    w.run(0.099)
    assert w.session.waiting
    assert w.session.deadline() == pytest.approx(w.now + 0.001)
    w.run(0.002)
    w.send(WaitMoved(0, 0))
    assert codes(w.responses()[1:]) == [E.MOTOR_NOT_READY, E.MOTOR_NOT_READY]
    assert w.session.deadline() is None


def test_wait_for_unknown_motor_is_e2_at_once(w: SessionRig) -> None:
    w.send(WaitMoved(9, 100))
    assert codes(w.responses()) == [E.INVALID_ADDRESS]


def test_backlog_limit_asks_for_back_pressure(tmp_path: Path) -> None:
    w = SessionRig(tmp_path, CONFIG, held=2, backlog=10)
    w.send(Move(0, True, 1, 0, 0))
    w.send(WaitMoved(0, 20_000), *[IsReady(1)] * 8)
    assert w.session.wants_input()
    w.send(IsReady(1))
    assert not w.session.wants_input()  # 10 answers owed
    w.send(StopMove(0, True))
    assert w.session.owed == 12
    assert len(w.responses()) == 12
    assert w.session.wants_input()


def test_the_end_of_a_session_drops_the_partial_frame(w: SessionRig) -> None:
    w.session.receive(frame(IsReady(0))[:4], w.now)
    assert w.session.end().partial_bytes == 4
    w.send(IsReady(0))
    assert codes(w.responses()) == [None]


def test_save_waypoint_on_lost_position_is_e4(w: SessionRig) -> None:
    w.engine.motors[0].position_lost = True
    w.send(SaveWayPoint(0), IsReady(0))
    assert codes(w.responses()) == [E.MOTOR_ERROR, None]
    assert w.engine.motors[0].waypoints == []


class Broken:
    """A dispatcher with a bug: every command raises."""

    def __init__(self) -> None:
        self.refusals: list[tuple[ErrorCode, str, Command | None]] = []

    def refused(
        self,
        code: ErrorCode,
        reason: str,
        command: Command | None = None,
        frame: bytes | None = None,
    ) -> None:
        self.refusals.append((code, reason, command))

    def handle(self, cmd: Command) -> Response:
        raise ZeroDivisionError("a bug")

    def wait_begin(self, cmd: WaitMoved, now: float) -> Response | Wait:
        return Response.ok()

    def wait_poll(self, wait: Wait, now: float) -> Response | None:
        return Response.ok()


def test_a_command_that_raises_is_e4_and_the_session_goes_on() -> None:
    port = Broken()
    session = LinkSession(port, OPTS, GAP)
    session.receive(frame(IsReady(0)) + frame(WaitMoved(0, 10)), 0.0)
    data = session.take_output()
    assert [decode_response(data[i : i + 5], OPTS).error_code for i in (0, 5)] == [
        E.MOTOR_ERROR,
        None,
    ]
    assert session.counters["internal_errors"] == 1
    # its reason is kept like any other error answer's (daemon/refusals.py)
    assert port.refusals == [(E.MOTOR_ERROR, "internal error (a bug: see the log)", IsReady(0))]


def test_a_command_that_raises_in_a_read_of_its_own_is_e4_each_time() -> None:
    # The second IsReady is a whole remembered frame read alone: the one-frame path.
    session = LinkSession(Broken(), OPTS, GAP)
    for n in (1, 2, 3):
        session.receive(frame(IsReady(0)), float(n))
        assert decode_response(session.take_output(), OPTS).error_code is E.MOTOR_ERROR
        assert session.counters["internal_errors"] == n


def test_recent_frames_pair_each_frame_with_its_answer(w: SessionRig) -> None:
    """The status's last frames: each with its own answer in words, a held one owed (None)
    until its WaitMoved is answered, a frame that failed its checks described as such; the
    fast path (a frame seen before, nothing held) records like the framer's path."""
    w.send(MoveTo(0, True, 400, 250, 0, 0))
    w.send(GetAbsPos(0))
    w.send(GetAbsPos(0))  # a frame seen before, read alone: the fast path
    w.send(WaitMoved(0, 10_000), IsReady(0))  # IsReady held behind the wait
    w.session.receive(corrupt(frame(IsReady(1)), 75), w.now)
    recent = w.session.describe_recent()
    assert [r["command"] for r in recent[:5]] == [
        "MoveTo(motor=0, dir=up, pos=400, speed=250, acc=0, dec=0)",
        "GetAbsPos(motor=0)",
        "GetAbsPos(motor=0)",
        "WaitMoved(motor=0, timeout_ms=10000)",
        "IsReady(motor=0)",
    ]
    assert [r["result"] for r in recent] == ["ok", "pos=0", "pos=0", None, None, None]
    assert str(recent[5]["command"]).startswith("bad frame (checksum)")
    assert recent[0]["frame"] == frame(MoveTo(0, True, 400, 250, 0, 0)).hex(" ")
    assert all(r["at_s"] == w.now for r in recent)
    w.run(5.0)
    results = [r["result"] for r in w.session.describe_recent()]
    assert results[3:] == ["ok", "ready", "E1 Invalid Command"]
    assert len(w.responses()) == 6
    for _ in range(40):
        w.send(IsReady(1))
    recent = w.session.describe_recent()
    assert len(recent) == 16 and {r["result"] for r in recent} == {"ready"}


def test_the_end_of_a_session_drops_what_was_owed_and_runs_nothing_kept(w: SessionRig) -> None:
    """A host's session ends behind a held WaitMoved: the wait, the kept frames and the
    partial frame go; the kept MoveTo never runs (its host is gone), the StopMove among
    them was carried out on arrival; the motor waited for goes on; the next host starts
    with nothing held and its answers pair with its own frames in the status."""
    w.send(Move(0, True, 1, 0, 0))
    assert codes(w.responses()) == [None]
    w.send(WaitMoved(0, 20_000), MoveTo(1, True, 100, 0, 0, 0), StopMove(1, True), IsReady(1))
    w.session.receive(frame(IsReady(0))[:3], w.now)
    ended = w.session.end()
    assert ended == Ended(partial_bytes=3, unsent=0, wait=1, held=3, discarded=2)
    assert ended.answers == 4
    assert not w.session.waiting and w.session.held == 0 and w.session.owed == 0
    assert w.session.counters["held_discarded"] == 2
    assert w.session.counters["stops_while_held"] == 1
    w.run(1.0)
    assert w.responses() == []  # nothing of the old session, ever
    assert w.engine.motors[1].idle and w.engine.motors[1].position == 0  # MoveTo not run
    assert not w.engine.motors[0].idle  # the waited-for motor goes on
    w.send(IsReady(1))
    assert codes(w.responses()) == [None]
    recent = w.session.describe_recent()
    assert [r["result"] for r in recent[-6:]] == [
        "ok",
        "not sent: its host's session ended",
        "not sent: its host's session ended",
        "not sent: its host's session ended",
        "not sent: its host's session ended",
        "ready",
    ]


def test_what_the_host_wrote_and_was_not_read_is_dropped_but_its_stop_carried_out(
    w: SessionRig,
) -> None:
    """The bytes the shell reads out at a session's end (its host wrote them; back pressure
    left them unread): framed on from the partial frame, never executed and never answered,
    but a StopMove among them is carried out; a frame that fails its checks is dropped
    alike, and what does not make a whole frame is counted as the partial frame."""
    w.send(Move(0, True, 1, 0, 0), Move(1, True, 1, 0, 0))
    assert codes(w.responses()) == [None, None]
    first = frame(SetPin(0, True))
    w.session.receive(first[:4], w.now)  # read before the end: the partial frame
    unread = (
        first[4:]
        + frame(MoveTo(1, True, 100, 0, 0, 0), StopMove(0, True))
        + corrupt(frame(StopMove(1, True)), 3)  # fails its checksum: not a StopMove
        + frame(SaveWayPoint(1), IsReady(1))[:-2]
    )
    frames_before = w.session.counters["frames"]
    ended = w.session.end(unread)
    assert ended == Ended(
        partial_bytes=8, unsent=0, wait=0, held=0, discarded=0, unread_frames=5, unread_stops=1
    )
    assert w.session.counters["frames"] == frames_before  # not taken as the session's
    w.run(1.0)
    assert w.responses() == []  # nothing answered, to anybody
    assert w.engine.motors[0].idle  # the StopMove carried out
    assert not w.engine.motors[1].idle  # the bad frame was no StopMove; no MoveTo ran
    w.send(GetPin(0))
    assert w.responses() == [Response.boolean(False)]  # the SetPin never ran
    w.send(IsReady(1))
    assert w.responses() == [Response.boolean(False)]


def test_answers_not_yet_taken_go_with_the_session(w: SessionRig) -> None:
    w.send(IsReady(0), GetAbsPos(0))
    assert w.session.end() == Ended(partial_bytes=0, unsent=2, wait=0, held=0, discarded=0)
    assert w.session.take_output() == b""


def test_outputs_counts_the_answers_taken_for_writing(w: SessionRig) -> None:
    """``outputs`` moves on when answers are taken, never while they are only made: a status
    reader that sees it move knows their commands' changes are whole (daemon/status)."""
    assert w.session.outputs == 0 and w.session.take_output() == b""
    w.send(IsReady(0), GetAbsPos(1))
    assert w.session.outputs == 0  # made, not taken
    assert len(w.responses()) == 2 and w.session.outputs == 1
    assert w.responses() == [] and w.session.outputs == 1  # nothing to take: no count
