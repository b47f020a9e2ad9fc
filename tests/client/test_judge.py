"""How the replay judges answers (client/judge.py, and the motions.py and motion_bounds.py it
judges with), on constructed recordings: each frame sent and answered at a chosen time, in
the recording and in the replay. No process, no clock.

The numbers in the comments are the derivations docs/trace.md describes: a stop's moment in
the motion's own time is its window less the motion command's; the device's own timing may
differ by j = 50 ms between the runs; positions may be off by 2 steps more."""

from __future__ import annotations

import pytest

from motorctl.client.conversation import analyse
from motorctl.client.judge import Tolerances, Verdict, compare
from motorctl.client.motion_bounds import envelope, speed_bound
from motorctl.client.motions import Span, recording, windows
from motorctl.client.replay import Outcome
from motorctl.protocol.capture.format import CaptureInfo, Direction, Record
from motorctl.protocol.codec import (
    CodecOptions,
    Command,
    ErrorCode,
    GetAbsPos,
    IsReady,
    Move,
    MoveTo,
    Response,
    SetPin,
    StopMove,
    WaitMoved,
    encode_command,
    encode_response,
)

OPTS = CodecOptions()
INFO = CaptureInfo(role="daemon", frame_gap_ms=10.0, port="/dev/test")
TOL = Tolerances(time_s=0.05, position=2, slide=0.0)  # the slide: its own tests
IN, OUT = Direction.TO_DEVICE, Direction.TO_HOST
OK = Response.ok()

#: (sent at s, command, its answer, answered at s)
Step = tuple[float, Command, Response, float]


def records(steps: list[Step]) -> list[Record]:
    out = []
    for sent, cmd, resp, answered in steps:
        out.append(Record(round(sent * 1e9), IN, encode_command(cmd, OPTS)))
        out.append(Record(round(answered * 1e9), OUT, encode_response(resp, OPTS)))
    return out


def judged(
    rec: list[Step],
    rep: list[Step],
    pacing: dict[int, float] | None = None,
    tol: Tolerances = TOL,
) -> list[Verdict]:
    a, b = analyse(records(rec), INFO), analyse(records(rep), INFO)
    return compare(a, b, windows(a), windows(b), tol, pacing or {}, 0)


def pos(p: int) -> Response:
    return Response.position(p)


def hard_stop(stop_at: float, final: int, speed: int = 250) -> list[Step]:
    """At rest at 0; a MoveTo of 8000 (SPEED 250: 1000 step/s); a hard stop; where it stood,
    twice."""
    return [
        (0.000, GetAbsPos(0), pos(0), 0.0002),
        (0.010, MoveTo(0, True, 8000, speed, 0, 0), OK, 0.011),
        (stop_at, StopMove(0, True), OK, stop_at + 0.001),
        (stop_at + 0.1, GetAbsPos(0), pos(final), stop_at + 0.1002),
        (stop_at + 0.2, GetAbsPos(0), pos(final), stop_at + 0.2002),
    ]


def test_a_position_after_a_hard_stop_is_judged_by_where_the_motion_could_be() -> None:
    rec = hard_stop(1.000, 950)
    # the recorded stop took effect 0.989..0.991 s into the motion, the replay's 0.999..1.001
    # s: at most 1000 step/s (its SPEED byte), -42..+62 ms apart with j: 908..1001 (no further
    # than 1000 step/s from its start) +-2
    near = judged(rec, hard_stop(1.010, 965))
    assert [v.result for v in near] == ["exact", "exact", "exact", "tolerated", "tolerated"]
    v = near[3]
    assert v.off == 15 and v.allowed == (906, 1003)
    assert "hard stop at frame #3" in v.why and "15 steps from the recorded" in v.why
    assert "its SPEED byte: 1000 step/s" in v.why
    # the second read at rest: exactly where the replay's stop left it
    assert "as the replay's earlier stop left it (+15)" in near[4].why
    for final in (1010, 900):
        far = judged(rec, hard_stop(1.010, final))
        assert [v.result for v in far][3:] == ["differs", "tolerated"], final
        assert "outside 906..1003" in far[3].why


def test_a_position_at_rest_must_stay_where_the_stop_left_it() -> None:
    rep = hard_stop(1.010, 965)
    rep[4] = (1.210, GetAbsPos(0), pos(966), 1.2102)
    v = judged(hard_stop(1.000, 950), rep)[4]
    assert v.result == "differs" and "not as the replay's earlier stop left it (+15)" in v.why


def test_without_a_speed_byte_twice_the_average_speed_bounds_it() -> None:
    """SPEED 0 (the device's default): 950 steps in 0.989 s less j from rest: at most
    2 x 950 / 0.939 = 2023 step/s, times 1.051 / 0.939 (it may still have been speeding up
    until the latest moment in question): 2264 step/s: 852..1093 (rounded outwards)."""
    rec = hard_stop(1.000, 950, speed=0)
    ok = judged(rec, hard_stop(1.010, 1050, speed=0))[3]
    assert ok.result == "tolerated" and ok.allowed == (852, 1093)
    assert "twice its average speed up to frame #4's position" in ok.why
    assert judged(rec, hard_stop(1.010, 1150, speed=0))[3].result == "differs"


def test_a_stop_right_after_the_start_as_with_fast_is_judged_from_the_start() -> None:
    """The replay's stop 1..3 ms into the motion: at most 3 steps from where it started."""
    rep = hard_stop(0.012, 3)
    near = judged(hard_stop(1.000, 950), rep)
    assert near[3].result == "tolerated" and near[3].allowed == (-2, 5)
    rep = hard_stop(0.012, 50)
    assert judged(hard_stop(1.000, 950), rep)[3].result == "differs"


def soft_stop(stop_at: float, final: int, end: float) -> list[Step]:
    """A MoveTo with ACC 10 and DEC 5 (a soft stop's end point moves up to 1 + 10/5 = 3 times
    its speed while it speeds up), stopped softly, waited for, read."""
    return [
        (0.000, GetAbsPos(0), pos(0), 0.0002),
        (0.010, MoveTo(0, True, 8000, 250, 10, 5), OK, 0.011),
        (stop_at, StopMove(0, False), OK, stop_at + 0.001),
        (stop_at + 0.1, WaitMoved(0, 5000), OK, end),
        (end + 0.1, GetAbsPos(0), pos(final), end + 0.1002),
    ]


def test_a_position_after_a_soft_stop_allows_for_its_ramp() -> None:
    """Where it came to rest: 1050 recorded, moving up to 3 x 1000 step/s over -42..+62 ms:
    924..1236 (+-2)."""
    rec = soft_stop(1.000, 1050, 1.3)
    got = judged(rec, soft_stop(1.010, 1200, 1.31))
    assert [v.result for v in got] == ["exact", "exact", "exact", "tolerated", "tolerated"]
    assert got[4].allowed == (922, 1238)
    assert "soft stop at frame #3" in got[4].why and "1 + ACC/DEC = 3.00" in got[4].why
    assert judged(rec, soft_stop(1.010, 1300, 1.31))[4].result == "differs"


def test_a_read_while_moving_is_judged_against_the_reads_around_it() -> None:
    def moving(first: int, second: int) -> list[Step]:
        return [
            (0.000, GetAbsPos(0), pos(0), 0.0002),
            (0.010, MoveTo(0, True, 8000, 250, 0, 0), OK, 0.011),
            (0.500, GetAbsPos(0), pos(first), 0.5002),
            (0.600, GetAbsPos(0), pos(second), 0.6002),
            (0.700, StopMove(0, True), OK, 0.701),
            (0.800, GetAbsPos(0), pos(640), 0.8002),
        ]

    rec = moving(430, 530)
    same = judged(rec, moving(470, 560))
    assert [v.result for v in same][2:4] == ["tolerated", "tolerated"]
    assert "read while moving" in same[2].why
    assert judged(rec, moving(620, 560))[2].result == "differs"  # 1000 step/s cannot


def test_with_no_speed_known_a_read_is_judged_by_order() -> None:
    """A Move with SPEED 0 from an unknown start: no speed bound; but a read cannot be past
    where the motion was later on."""

    def run(first: int) -> list[Step]:
        return [
            (0.010, Move(0, True, 0, 0, 0), OK, 0.011),
            (0.500, GetAbsPos(0), pos(first), 0.5002),
            (0.700, GetAbsPos(0), pos(300), 0.7002),
            (0.800, StopMove(0, True), OK, 0.801),
        ]

    rec = run(100)
    assert judged(rec, run(250))[1].result == "tolerated"
    late = judged(rec, run(5000))[1]
    assert late.result == "differs" and "no speed known" in late.why


def ready_polls(answers: list[tuple[float, bool]]) -> list[Step]:
    steps: list[Step] = [
        (0.000, GetAbsPos(0), pos(0), 0.0002),
        (0.010, MoveTo(0, True, 1000, 250, 0, 0), OK, 0.011),
    ]
    steps += [(t, IsReady(0), Response.boolean(r), t + 0.0001) for t, r in answers]
    return steps


def test_is_ready_is_judged_by_when_the_motion_ended() -> None:
    """Recorded: busy at 0.5 and 0.9, ready at 1.1: it ended 0.889..1.090 s into the
    motion; the replay may say otherwise within 50 ms of that."""
    rec = ready_polls([(0.5, False), (0.9, False), (1.1, True)])
    early = judged(rec, ready_polls([(0.5, False), (0.9, True), (1.1, True)]))
    assert [v.result for v in early][2:] == ["exact", "tolerated", "exact"]
    assert "ready: its end here by 0.890 s into the motion" in early[3].why
    late = judged(rec, ready_polls([(0.5, False), (0.9, False), (1.1, False)]))
    assert late[4].result == "tolerated"
    wrong = judged(rec, ready_polls([(0.5, True), (0.9, True), (1.1, True)]))
    assert wrong[2].result == "differs" and "outside 0.839..1.140 s" in wrong[2].why


def waited(answered: float) -> list[Step]:
    return [
        (0.000, GetAbsPos(0), pos(0), 0.0002),
        (0.010, MoveTo(0, True, 1000, 250, 0, 0), OK, 0.011),
        (0.100, WaitMoved(0, 5000), OK, answered),
        (answered + 0.05, GetAbsPos(0), pos(1000), answered + 0.0502),
    ]


def test_a_wait_moved_hold_is_judged_by_when_the_move_ended() -> None:
    rec = waited(1.0)
    got = judged(rec, waited(1.03))
    assert [v.result for v in got] == ["exact", "exact", "tolerated", "exact"]
    assert "its end here 0.969..1.020 s into the motion, recorded 0.939..0.990 s" in got[2].why
    held = judged(rec, waited(1.3))[2]
    assert held.result == "differs" and "outside 0.889..1.040 s" in held.why


def test_a_motion_may_slide_by_a_share_of_its_time() -> None:
    """A device's late steps slide the rest of a move (docs/timing.md), the more the longer
    it runs: a move of 3 s that ends 120 ms later than recorded (4 %) is within 50 ms and a
    5 % slide (150 ms over 3 s), said with the figures; one 300 ms later (10 %) is not, nor
    is one 300 ms earlier; without the slide the 120 ms are a difference."""

    def long_wait(answered: float) -> list[Step]:
        return [
            (0.000, GetAbsPos(0), pos(0), 0.0002),
            (0.010, MoveTo(0, True, 3000, 250, 0, 0), OK, 0.011),  # 1000 step/s: 3 s
            (0.100, WaitMoved(0, 10_000), OK, answered),
            (answered + 0.05, GetAbsPos(0), pos(3000), answered + 0.0502),
        ]

    slide = Tolerances(time_s=0.05, position=2, slide=0.05)
    rec = long_wait(3.0)
    later = judged(rec, long_wait(3.12), tol=slide)[2]
    assert later.result == "tolerated", later.why
    assert "device timing +-50 ms and a slide of up to 5% of its 3.1" in later.why
    assert judged(rec, long_wait(3.12))[2].result == "differs"  # TOL: no slide
    assert judged(rec, long_wait(3.3), tol=slide)[2].result == "differs"
    assert judged(rec, long_wait(2.7), tol=slide)[2].result == "differs"


def test_a_position_while_moving_may_be_as_far_behind_as_its_slide() -> None:
    """A read 2 s into a move at 1000 step/s whose motor slid 80 ms more than recorded: 80
    steps behind the recorded read, beyond 50 ms of device timing (plus the windows) but
    within a 5 % slide of its 2 s; 250 steps behind is not."""

    def read_at(p: int) -> list[Step]:
        return [
            (0.000, GetAbsPos(0), pos(0), 0.0002),
            (0.010, MoveTo(0, True, 8000, 250, 0, 0), OK, 0.011),
            (2.011, GetAbsPos(0), pos(p), 2.0112),
        ]

    slide = Tolerances(time_s=0.05, position=2, slide=0.05)
    rec = read_at(2000)
    assert judged(rec, read_at(1920))[2].result == "differs"  # TOL: no slide
    v = judged(rec, read_at(1920), tol=slide)[2]
    assert v.result == "tolerated" and "a slide of up to 5% of its 2.00" in v.why, v.why
    assert judged(rec, read_at(1750), tol=slide)[2].result == "differs"


def test_an_answer_the_replay_sent_too_late_to_judge_is_not_called_a_difference() -> None:
    """The WaitMoved went 200 ms late: with j widened by that, its hold fits: 'pacing'."""
    rec = waited(1.0)
    v = judged(rec, waited(1.3), pacing={3: 0.2})[2]
    assert v.result == "pacing" and "the replay sent frame #3 200 ms late" in v.why
    assert judged(rec, waited(2.0), pacing={3: 0.2})[2].result == "differs"  # beyond that too
    out = Outcome(4, [v], [], None, [0.001, 0.2])
    assert out.status == 3 and out.pacing()["max_ms"] == 200.0


def test_an_answer_that_came_late_while_the_motion_ran_is_a_stall_not_a_difference() -> None:
    """The device answered a read 300 ms later than recorded while the motor moved: this
    machine stalled, and the motion slid with it (300 steps behind at the stop): not judged;
    with j 50 ms + 300 ms it would fit."""
    rec = hard_stop(1.000, 950)
    rec.insert(2, (0.5, GetAbsPos(0), pos(490), 0.5002))
    rep = hard_stop(1.000, 650)
    rep.insert(2, (0.5, GetAbsPos(0), pos(490), 0.8))
    got = judged(rec, rep)
    assert got[4].result == "pacing", got[4].why
    assert "got the answer to frame #3 300 ms later than recorded" in got[4].why
    rep[4] = (1.1, GetAbsPos(0), pos(550), 1.1002)  # further behind than even that allows
    assert judged(rec, rep)[4].result == "differs"


def test_a_changed_answer_is_named_with_its_frame() -> None:
    def pins(code: ErrorCode) -> list[Step]:
        return [
            (0.0, IsReady(0), Response.boolean(True), 0.0001),
            (0.1, SetPin(5, True), Response.error(code), 0.1001),
        ]

    got = judged(pins(ErrorCode.INVALID_COMMAND), pins(ErrorCode.INVALID_ADDRESS))
    assert [v.result for v in got] == ["exact", "differs"]
    assert got[1].frame == 2 and "E1 Invalid Command" in got[1].recorded
    assert "E2 Invalid Address" in got[1].replayed


def test_a_stop_sent_behind_a_held_wait_moved_is_the_stop_of_that_motion() -> None:
    """The host waits, then stops the motor while the WaitMoved is held (executed on arrival,
    answered after the WaitMoved): where it stands is judged as after a hard stop."""

    def run(stop_at: float, final: int) -> list[Step]:
        return [
            (0.000, GetAbsPos(0), pos(0), 0.0002),
            (0.010, MoveTo(0, True, 8000, 250, 0, 0), OK, 0.011),
            (0.100, WaitMoved(0, 20_000), OK, stop_at + 0.0005),
            (stop_at, StopMove(0, True), OK, stop_at + 0.001),
            (stop_at + 0.1, GetAbsPos(0), pos(final), stop_at + 0.1002),
        ]

    rec = run(1.000, 950)
    near = judged(rec, run(1.010, 965))
    assert [v.result for v in near] == ["exact", "exact", "tolerated", "exact", "tolerated"]
    assert "after the hard stop at frame #4" in near[4].why
    assert judged(rec, run(1.010, 1100))[4].result == "differs"


def test_queued_motions_are_judged_within_all_they_can_reach() -> None:
    def queued(read: int) -> list[Step]:
        return [
            (0.000, GetAbsPos(0), pos(0), 0.0002),
            (0.010, MoveTo(0, True, 1000, 0, 0, 0), OK, 0.011),
            (0.020, MoveTo(0, True, -500, 0, 0, 0), OK, 0.021),
            (0.500, GetAbsPos(0), pos(read), 0.5002),
            (0.600, WaitMoved(0, 5000), OK, 2.0),
        ]

    rec = queued(800)
    got = judged(rec, queued(-400))[3]
    assert got.result == "tolerated" and got.allowed == (-502, 1002)
    assert "more than one motion queued" in got.why
    assert judged(rec, queued(1100))[3].result == "differs"


def test_the_speed_byte_is_not_trusted_when_the_recording_moved_faster() -> None:
    """SPEED 1 would be 4 step/s by the protocol's factor; the recording moved 950 steps in
    a second, so the device's [units] differ: the recording's average bounds it instead."""
    rec = analyse(records(hard_stop(1.000, 950, speed=1)), INFO)
    ep = recording(rec, windows(rec), 0.05).episodes[0]
    bound = speed_bound(ep, 0.9, 0.05)  # up to 0.9 s: before its known position
    assert bound.v == pytest.approx(2 * 950 / (0.989 - 0.05), rel=1e-3)
    assert "twice its average speed" in bound.why


def test_envelope_bounds_a_one_way_motion() -> None:
    """At most 100 step/s, 10 steps from its start at 0.1 s: at 0.3 s (+-0.01 s) it is 10..31
    from that, and no more than 30 from its start."""
    lo, hi = envelope([(Span(0.1, 0.1), 10.0)], Span(0.3, 0.3), 100.0, 0.01, True, None)
    assert lo == pytest.approx(10.0) and hi == pytest.approx(30.0)
    lo, hi = envelope([(Span(0.1, 0.1), 10.0)], Span(0.3, 0.3), 100.0, 0.01, False, None)
    assert lo == pytest.approx(10.0) and hi == pytest.approx(31.0)
    # no speed known: only that it is no less far than it was earlier
    lo, hi = envelope([(Span(0.1, 0.1), 10.0)], Span(0.3, 0.3), None, 0.01, True, 25.0)
    assert (lo, hi) == (10.0, 25.0)
