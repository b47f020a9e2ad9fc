"""How ``motorctl replay`` judges the device's answers against a recording's (docs/trace.md,
"How the answers are judged"); the recording's motions: :mod:`motorctl.client.motions`;
what they allow: :mod:`motorctl.client.motion_bounds`.

Pure computation: two analysed conversations (the recording's and the replay's), when each
frame was sent and answered on each run's own clock, and the replay's pacing in; one
:class:`Verdict` per frame out. No I/O, no clock; runs on the caller's thread.

Every answer is compared byte for byte, except those that timing decides, which are judged
from the motion they came from:

- a position read while a motor moves, and the position it stands at after a stop (hard or
  soft), by where that motion could have been at the moment the replay's read or stop took
  effect: somewhere in its window (from sending the frame to receiving its answer), counted
  from the replay's motion command (its window too). The recording tells where the same
  motion was at its own windows (its reads, where its stop left it); between them the motion
  moves one way, at most ``v`` step/s (:func:`speed_bound`), so a replay window that lies
  ``dt`` after (before) a recorded one may be at most ``v * dt`` further (less far). The
  device's own timing (when a motion starts after its answer, how far its steps lag behind
  their plan, when its end is seen) may differ between the two runs by the time tolerance
  ``j``, which widens every such ``dt``;
- whether a motion had ended (IsReady, a SaveHome/SaveWayPoint's E3, a WaitMoved's hold and
  timeout), by when that motion ended in the recording, in its own time, moved by what the
  replay changed (a soft stop that came later, a motion that started elsewhere) and ``j``;
- a position at rest after such a tolerated stop: exactly where the replay's own stop left
  the motor (the difference is carried until a motion to an absolute target ends).

Where a judgment fails, the timing is looked at: if, while that motion ran, the replay sent
a frame later than ``j`` after it was due or got an answer later after its frame than
recorded by more than ``j`` (a stall), and the answer fits with ``j`` widened by that, the
verdict is ``pacing`` (not judged: the timing the tolerance assumes was not kept), not
``differs``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from motorctl.client.conversation import ANSWER, Conversation, Frame, Row
from motorctl.client.motion_bounds import Check, Replayed, end_shift, gap, positions
from motorctl.client.motions import Episode, Span, ends, motion, recording, wrapped
from motorctl.protocol.codec import (
    GetAbsPos,
    SaveHome,
    SaveWayPoint,
    WaitMoved,
    describe,
    describe_answer,
)

TIME_TOLERANCE_S = 0.05
SLIDE_TOLERANCE = 0.05
POSITION_TOLERANCE = 2

# --- verdicts --------------------------------------------------------------------------------


@dataclass
class Tolerances:
    """How far a replay may differ from its recording and still pass: in time, in position,
    and the slide of a long motion behind its plan."""

    time_s: float = TIME_TOLERANCE_S
    position: int = POSITION_TOLERANCE
    #: how far a motion may slide behind its plan, as a share of its time so far: a
    #: device's late steps slide the rest of a move (docs/timing.md), the more the longer it
    #: runs, and differently in two runs
    slide: float = SLIDE_TOLERANCE

    def device_timing(self, j: float, t: float) -> tuple[float, str]:
        """The device timing allowed ``t`` s into a motion, from ``j`` (the time
        tolerance, maybe widened by the pacing): j and the slide over t; and its text."""
        slid = self.slide * max(0.0, t)
        text = f"device timing +-{j * 1000:.0f} ms"
        if slid >= 0.0005:
            text += (
                f" and a slide of up to {self.slide * 100:g}% of its {t:.3f} s "
                f"(+-{slid * 1000:.0f} ms)"
            )
        return j + slid, text


@dataclass
class Verdict:
    """One replayed command judged against its recording: what each said, the result and
    why, and for positions how far off and what was allowed."""

    frame: int
    t_s: float
    command: str
    recorded: str
    replayed: str
    result: str  # "exact", "tolerated", "differs", "pacing", "not compared"
    why: str = ""
    off: int | None = None  # positions: replayed - recorded (steps)
    allowed: tuple[int, int] | None = None  # positions: the range judged acceptable

    def line(self) -> str:
        return (
            f"frame #{self.frame} at {self.t_s:.6f} s {self.command}: recorded "
            f"{self.recorded}, replayed {self.replayed}" + (f" ({self.why})" if self.why else "")
        )


@dataclass
class Context:
    """Everything one judgment needs."""

    rec_spans: dict[int, Span]
    rep_spans: dict[int, Span]
    tol: Tolerances
    pacing: dict[int, float]  # frame number -> how late the replay sent it (s)
    episodes: dict[int, Replayed] = field(default_factory=dict)  # by first frame
    offsets: dict[int, int | None] = field(default_factory=dict)  # motor -> at rest
    unknown: dict[int, str] = field(default_factory=dict)  # motor -> why its offset is None
    waypoints: dict[tuple[int, int], int | None] = field(default_factory=dict)
    home: dict[int, int | None] = field(default_factory=dict)


def _frame_pos(row: Row) -> int:
    assert row.response is not None
    return row.response.as_position


def judge_position(
    f: Frame, role: str, ep: Episode, b: Row, ctx: Context, j0: float, j: float, timing: str
) -> Check:
    """A position that timing decides (role "moving", "after_soft", "rest"); ``j0``: the
    time tolerance, ``j``: the device timing allowed, the motion's slide added (``timing``,
    in words)."""
    assert f.answer is not None
    rp = ctx.episodes[ep.first.number]
    pa, pb = _frame_pos(f.answer), _frame_pos(b)
    tol = ctx.tol.position
    if role == "moving":
        tau = ctx.rep_spans[f.number].since(rp.start)
        rec_tau = ctx.rec_spans[f.number].since(ep.start)
        check = positions(ep, rp, "f", tau, j, tol, j0)
        what = f"read while moving, {gap(rec_tau, tau)} from the recorded read in its time"
    elif rp.stop is None or ep.stop_tau is None:
        return Check(False, "its stop was not answered in the replay")
    else:
        tau = rp.stop.since(rp.start)
        which = "after_soft" if role == "after_soft" else ("f" if ep.hard else "q")
        check = positions(ep, rp, which, tau, j, tol, j0)
        kind = "hard" if ep.hard else "soft"
        assert ep.stop is not None
        what = (
            f"after the {kind} stop at frame #{ep.stop.number}, which took effect "
            f"{gap(ep.stop_tau, tau)} from the recorded one in the motion's time"
        )
    if check.allowed is None:
        return Check(True, f"{what}; {check.why}", off=wrapped(pb - pa))
    lo, hi = check.allowed
    fits = lo <= pb <= hi
    return Check(
        fits,
        f"{what}: {abs(wrapped(pb - pa))} steps from the recorded; "
        f"{'allowed' if fits else 'outside'} {lo}..{hi} ({check.why}; "
        f"{timing}, +-{tol} steps)",
        off=wrapped(pb - pa),
        allowed=check.allowed,
    )


def judge_end(
    f: Frame, ep: Episode, b: Row, ctx: Context, j0: float, j: float, timing: str
) -> Check:
    """An answer that says whether the motion had ended, against when it ended recorded;
    ``j0``: the time tolerance (when an end is seen, when a stop takes effect), ``j``: the
    device timing allowed for the end itself, the motion's slide added (``timing``, in
    words)."""
    rp = ctx.episodes[ep.first.number]
    cmd = f.command
    assert cmd is not None and b.response is not None
    seen = ends(cmd, b.response, ctx.rep_spans[f.number], rp.start, j0)
    shift, shift_why = end_shift(ep, rp, j0)
    expect = Span(ep.end.lo + shift.lo - j, ep.end.hi + shift.hi + j)
    said = describe_answer(cmd, b.response)
    if seen is None:
        return Check(False, f"{said}: says nothing of the motion's end")
    fits = seen.meets(expect)
    because = f"; {shift_why}" if shift_why else ""
    return Check(
        fits,
        f"{said}: its end here {seen.text()} into the motion, recorded {ep.end.text()}; "
        f"{'allowed' if fits else 'outside'} {expect.text()} ({timing}{because})",
    )


# --- the comparison --------------------------------------------------------------------------


def _show(row: Row | None, f: Frame | None) -> str:
    if row is None:
        return "no answer"
    text = describe_answer(f.command if f else None, row.response) if row.response else row.text
    return f"{row.data.hex(' ')} ({text})"


def _both_ack(a: Row, b: Row) -> bool:
    return (
        a.kind == ANSWER
        and b.kind == ANSWER
        and a.response is not None
        and b.response is not None
        and a.response.ack
        and b.response.ack
    )


class Judge:
    """Goes through the recording's frames in order, keeping the replay's side of each
    motion (:class:`Replayed`): when it started, how far its start and rest positions are
    from the recording's."""

    def __init__(self, rec: Conversation, rec_spans: dict[int, Span], ctx: Context) -> None:
        self.ctx = ctx
        self.rec = recording(rec, rec_spans, ctx.tol.time_s)
        self._pacing_why = ""

    def verdict(self, f: Frame, a: Row, b: Row, v: Verdict) -> Verdict:
        role, ep = self.rec.roles.get(f.number, ("", None))
        if ep is not None:
            self._follow(f, role, ep)
        check = self._timed(f, role, ep, a, b)
        if check is None:
            check = self._exact(f, a, b)
        if check is not None:
            v.why, v.off, v.allowed = check.why, check.off, check.allowed
            if check.fits:
                v.result = "tolerated"
            elif ep is not None and self._pacing(f, role, ep, a, b):
                v.result, v.why = "pacing", self._pacing_why
            else:
                v.result = "differs"
        self._after(f, role, ep, a, b, v.result == "differs")
        return v

    def _timed(
        self, f: Frame, role: str, ep: Episode | None, a: Row, b: Row, j: float | None = None
    ) -> Check | None:
        """The judgment of an answer timing decides; None for the others. ``j``: the time
        tolerance (None: the configured one), to which the slide over the motion's time
        until this answer is added."""
        if ep is None or f.number not in self.ctx.rep_spans:
            return None
        if ep.first.number not in self.ctx.episodes:  # its start was not answered here
            return None
        t = self.ctx.rep_spans[f.number].since(self.ctx.episodes[ep.first.number].start).hi
        j0 = self.ctx.tol.time_s if j is None else j
        j, timing = self.ctx.tol.device_timing(j0, t)
        if role in ("moving", "after_soft", "rest") and _both_ack(a, b):
            return judge_position(f, role, ep, b, self.ctx, j0, j, timing)
        if role == "ended?" and b.response is not None:
            held = isinstance(f.command, WaitMoved) and _both_ack(a, b)
            if a.data == b.data and not held:
                return None
            return judge_end(f, ep, b, self.ctx, j0, j, timing)
        return None

    def _exact(self, f: Frame, a: Row, b: Row) -> Check | None:
        """A position at rest where an earlier tolerated stop left the replay's motor
        elsewhere: exactly that far; every other answer: byte for byte (None: equal)."""
        cmd = f.command
        if isinstance(cmd, GetAbsPos) and _both_ack(a, b):
            off = self.ctx.offsets.get(cmd.motor, 0)
            got = wrapped(_frame_pos(b) - _frame_pos(a))
            if off is None:
                why = self.ctx.unknown.get(cmd.motor, "")
                return Check(True, f"not judged: its position here was unknown ({why})", off=got)
            if off:
                fits = got == off
                return Check(
                    fits,
                    f"at rest, {got:+d} steps from the recorded: "
                    f"{'as' if fits else 'not as'} the replay's earlier stop left it "
                    f"({off:+d})",
                    off=got,
                )
        if a.data == b.data:
            return None
        return Check(False, "")

    def _lateness(self, first: int, last: int) -> tuple[float, str]:
        """The worst timing the replay could not keep between frames ``first`` and
        ``last``: a frame it sent late after it was due, or an answer that came later after
        its frame than recorded (the device, or this machine, stalled: a motion running
        then slid as far). A WaitMoved's hold is the motion's, not counted."""
        worst, what = 0.0, ""
        for n in range(first, last + 1):
            sent = self.ctx.pacing.get(n, 0.0)
            if sent > worst:
                worst, what = sent, f"sent frame #{n} {sent * 1000:.0f} ms late"
            rec, rep = self.ctx.rec_spans.get(n), self.ctx.rep_spans.get(n)
            if rec is None or rep is None or n in self.rec.holds:
                continue
            slow = (rep.hi - rep.lo) - (rec.hi - rec.lo)
            if slow > worst:
                worst, what = slow, f"got the answer to frame #{n} {slow * 1000:.0f} ms later"
        return worst, what

    def _pacing(self, f: Frame, role: str, ep: Episode, a: Row, b: Row) -> bool:
        """Whether the replay could not keep the timing this judgment depends on within j
        (:meth:`_lateness`), and the answer fits with j widened by that (the why:
        ``_pacing_why``)."""
        late, what = self._lateness(ep.first.number, f.number)
        if late <= self.ctx.tol.time_s:
            return False
        check = self._timed(f, role, ep, a, b, self.ctx.tol.time_s + late)
        if check is None or not check.fits:
            return False
        self._pacing_why = (
            f"not judged: while this motion ran the replay {what} than recorded, more than "
            f"the {self.ctx.tol.time_s * 1000:.0f} ms of device timing its tolerance assumes; "
            f"with that much more: {check.why}"
        )
        return True

    def _follow(self, f: Frame, role: str, ep: Episode) -> None:
        """The replay's side of the motion: when it started, from how far off the
        recording's start, its stop; and where the motor will be at rest after it."""
        span = self.ctx.rep_spans.get(f.number)
        if span is None:
            return
        offsets = self.ctx.offsets
        if role == "start":
            self.ctx.episodes[ep.first.number] = Replayed(
                span, offsets.get(ep.motor, 0), unknown=self.ctx.unknown.get(ep.motor, "")
            )
            offsets[ep.motor] = self._end_offset(ep)
            if offsets[ep.motor] is None:
                self.ctx.unknown[ep.motor] = (
                    f"the motion started at frame #{f.number} ended where the replay did not "
                    "read it"
                )
        elif role == "stop" and f is ep.stop and ep.first.number in self.ctx.episodes:
            self.ctx.episodes[ep.first.number].stop = span

    def _end_offset(self, ep: Episode) -> int | None:
        """Where the replay's motor stands after ``ep`` relative to the recording's: 0 after a
        motion to an absolute target, unknown after a stop until it is read."""
        if ep.ended != "done" or len(ep.commands) != 1:
            return None
        cmd = ep.commands[0]
        ends = motion(cmd).ends
        if ends == "waypoint":
            return self.ctx.waypoints.get((ep.motor, getattr(cmd, "waypoint")), 0)  # noqa: B009
        if ends == "home":
            return self.ctx.home.get(ep.motor, 0)
        return 0  # at an absolute target, or homed (a motion that never ends has not ended)

    def _after(
        self, f: Frame, role: str, ep: Episode | None, a: Row, b: Row, differed: bool
    ) -> None:
        """A position read at rest tells where the replay's motor is against the recording's
        (unless it was the difference: then that is unknown until the next such read); saves
        keep it for the motions to them."""
        cmd, offsets = f.command, self.ctx.offsets
        if not _both_ack(a, b) or cmd is None:
            return
        motor = getattr(cmd, "motor", -1)
        if isinstance(cmd, GetAbsPos) and (role == "rest" or ep is None):
            if differed:
                offsets[motor] = None
                self.ctx.unknown[motor] = f"frame #{f.number} differed"
            elif role == "rest" or offsets.get(motor, 0) is None:
                offsets[motor] = wrapped(_frame_pos(b) - _frame_pos(a))
        elif isinstance(cmd, SaveWayPoint):
            assert a.response is not None
            self.ctx.waypoints[(motor, a.response.payload[0])] = offsets.get(motor, 0)
        elif isinstance(cmd, SaveHome):
            self.ctx.home[motor] = offsets.get(motor, 0)


def compare(
    rec: Conversation,
    rep: Conversation,
    rec_spans: dict[int, Span],
    rep_spans: dict[int, Span],
    tol: Tolerances,
    pacing: dict[int, float],
    t0: int,
) -> list[Verdict]:
    """One verdict per recorded frame (and one per frame the replay had beyond them)."""
    judge = Judge(rec, rec_spans, Context(rec_spans, rep_spans, tol, pacing))
    out: list[Verdict] = []
    rep_frames = {f.number: f for f in rep.frames}
    for f in rec.frames:
        name = describe(f.command) if f.command is not None else f"bad frame {f.data.hex(' ')}"
        g = rep_frames.get(f.number)
        a, b = f.answer, (g.answer if g is not None else None)
        v = Verdict(f.number, (f.t_ns - t0) / 1e9, name, _show(a, f), _show(b, f), "exact")
        if a is None:
            v.recorded, v.result = "no answer (the recording ends)", "not compared"
        elif b is None:
            v.result = "differs"
        else:
            v = judge.verdict(f, a, b, v)
        out.append(v)
    for g in rep.frames[len(rec.frames) :]:
        name = describe(g.command) if g.command else "bad frame"
        out.append(
            Verdict(g.number, 0.0, name, "not in the recording", _show(g.answer, g), "differs")
        )
    return out
