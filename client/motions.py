"""What a recording says of its motions, and where a motion could have been at a moment of
a replay (docs/trace.md, "How the answers are judged"): the half of the replay's judge that
knows motion; :mod:`motorctl.client.judge` is the other half.

A motion (an :class:`Episode`) runs from rest to rest; the recording's answers say when it
started and ended, where it was at some of its moments (its reads, where a stop left it),
when it ended. Moments are windows (:class:`Span`: a command took effect at one moment
between sending its frame and receiving its answer) counted from the motion's command.
:func:`positions` bounds where the same motion may be at a moment of the replay: it moves
one way, at most :func:`speed_bound` step/s; the device's own timing may differ by ``j``.

Over 500 lines on purpose: the motions' reading and the bounds on them are one derivation
(docs/trace.md writes it out), read together.

Pure computation; runs on the caller's thread.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from motorctl.client.trace import Conversation, Frame
from motorctl.protocol.codec import (
    POS_MAX,
    POS_MIN,
    Command,
    GetAbsPos,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    Response,
    SaveHome,
    SaveWayPoint,
    StopMove,
    WaitMoved,
)

#: the protocol's unit factors (PROTOCOL.md section 3; a device's [units] may differ, which
#: the recording then shows: see :func:`speed_bound`)
MOVE_SPEED_FACTOR = 4.0  # MoveTo, MoveToWayPoint: step/s per SPEED
RUN_SPEED_FACTOR = 4096.0  # InitMove, Move
MOTION = (InitMove, MoveTo, Move, GoHome, MoveToWayPoint)
INF = math.inf
_POS_SPAN = POS_MAX - POS_MIN + 1


def wrapped(diff: int) -> int:
    """A difference of two 24-bit positions, the short way round."""
    return (diff - POS_MIN) % _POS_SPAN + POS_MIN


# --- time ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Span:
    """Something happened at one moment in ``lo..hi`` (s)."""

    lo: float
    hi: float

    def since(self, start: Span) -> Span:
        """The same moment counted from something that happened in ``start``."""
        return Span(self.lo - start.hi, self.hi - start.lo)

    def meets(self, other: Span) -> bool:
        return self.lo <= other.hi and other.lo <= self.hi

    def text(self) -> str:
        if self.lo == -INF:
            return "any time" if self.hi == INF else f"by {self.hi:.3f} s"
        if self.hi == INF:
            return f"after {self.lo:.3f} s"
        return f"{self.lo:.3f}..{self.hi:.3f} s"


def windows(conv: Conversation, sent_ns: dict[int, int] | None = None) -> dict[int, Span]:
    """Each answered frame's window on its run's clock: from its last byte being sent (or
    read, in the recorder's trace) to its answer. ``sent_ns``: the replay's own send times
    (when the write of the frame's last byte began), frame number -> ns."""
    out: dict[int, Span] = {}
    for f in conv.frames:
        if f.answer is None:
            continue
        lo = sent_ns.get(f.number, f.t_ns) if sent_ns is not None else f.t_ns
        out[f.number] = Span(lo / 1e9, f.answer.t_ns / 1e9)
    return out


@dataclass
class Check:
    """One timing judgment: does the replay's answer fit, and the sentence saying why."""

    fits: bool
    why: str
    off: int | None = None
    allowed: tuple[int, int] | None = None


# --- the recording's motions -----------------------------------------------------------------


@dataclass
class Point:
    """Where a motion was (``pos``) at some moment ``tau`` of its own time (from its motion
    command), learned from frame ``frame``."""

    frame: int
    tau: Span
    pos: int


@dataclass
class Episode:
    """One motion of one motor in the recording, from rest to rest: its commands (more than
    one when queued), where it started, its reads while moving, its stop, its end."""

    motor: int
    first: Frame
    start: Span  # the first command's window
    p0: int | None  # the position it started from, when the recording knows it
    commands: list[Command] = field(default_factory=list)
    reads: list[Point] = field(default_factory=list)  # while moving, before any stop
    stop: Frame | None = None
    hard: bool = False
    stop_tau: Span | None = None
    rest: Point | None = None  # where a stop left it (at the stop's time)
    end: Span = field(default_factory=lambda: Span(-INF, INF))  # when it ended (its time)
    ended: str = ""  # "done", "stopped", "fault"
    target: int | None = None  # where it ends when it completes
    targets: list[int | None] = field(default_factory=list)  # each command's

    @property
    def simple(self) -> bool:
        """One command from rest: its speed rises, holds and falls (a trapezoid), once."""
        return len(self.commands) == 1 and not isinstance(self.commands[0], InitMove)

    @property
    def homing(self) -> bool:
        return any(isinstance(c, InitMove) for c in self.commands)

    @property
    def direction(self) -> int:
        """+1 counting up, -1 down, 0 unknown (or more than one command)."""
        if len(self.commands) != 1:
            return 0
        cmd = self.commands[0]
        if isinstance(cmd, Move | InitMove):
            return 1 if cmd.direction else -1
        if self.target is not None and self.p0 is not None:
            return _sign(wrapped(self.target - self.p0))
        known = [p.pos for p in self.reads] + ([self.rest.pos] if self.rest else [])
        if self.p0 is not None:
            known.insert(0, self.p0)
        return _sign(wrapped(known[-1] - known[0])) if len(known) >= 2 else 0


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


@dataclass
class Recording:
    """The recording's motions, and what each frame is to one (``roles``: frame number ->
    role, episode): "start" (its first motion command), "moving" (a position read while it
    moved, before any stop), "stop" (its StopMove), "after_soft" (a position read after its
    soft stop, maybe still moving), "rest" (the first position read at rest after a stop),
    "ended?" (an answer that says whether it had ended)."""

    episodes: list[Episode] = field(default_factory=list)
    roles: dict[int, tuple[str, Episode]] = field(default_factory=dict)
    holds: set[int] = field(default_factory=set)  # WaitMoved frames: answered when it stood


def ends(cmd: Command, resp: Response, span: Span, start: Span, j: float) -> Span | None:
    """When a motion ended (its own time), as this answer says; None: it says nothing."""
    lo, hi = span.since(start).lo, span.since(start).hi
    if isinstance(cmd, IsReady) and resp.ack:
        return Span(lo, INF) if not resp.as_bool else Span(-INF, hi)
    if isinstance(cmd, SaveHome | SaveWayPoint):
        if resp.ack:
            return Span(-INF, hi)
        return Span(lo, INF) if resp.payload[0] == 0xE3 else None
    if isinstance(cmd, WaitMoved):
        if resp.ack:  # answered once the motor stood: within j of its end when it was held
            held = span.hi - span.lo > j
            return Span(span.hi - j - start.hi if held else -INF, hi)
        if resp.payload[0] == 0xE3:  # timed out: still moving TIMEOUT after it was taken up
            return Span(lo + cmd.timeout_ms / 1000.0, INF)
        return None
    return None


def _intersect(a: Span, b: Span) -> Span:
    return Span(max(a.lo, b.lo), min(a.hi, b.hi))


class _Builder:
    """Reads the recording's answers in order into episodes (:func:`recording`)."""

    def __init__(self, frames: list[Frame], spans: dict[int, Span], j: float) -> None:
        self.frames = frames
        self.spans = spans
        self.j = j
        self.rec = Recording()
        self.current: dict[int, Episode] = {}
        self.rest_pos: dict[int, int | None] = {}
        self.waiting_rest: dict[int, Episode] = {}  # stopped, where it stands not read yet
        self.waypoints: dict[tuple[int, int], int | None] = {}
        self.home: dict[int, int | None] = {}

    def frame(self, f: Frame) -> None:
        cmd, row = f.command, f.answer
        motor = getattr(cmd, "motor", None)
        if cmd is None or row is None or row.response is None or motor is None:
            return
        resp, span = row.response, self.spans[f.number]
        ep = self.current.get(motor)
        if isinstance(cmd, WaitMoved):
            self.rec.holds.add(f.number)
        if isinstance(cmd, GetAbsPos) and resp.ack:
            self._position(f, motor, resp.as_position, ep, span)
        elif ep is not None and not resp.ack and resp.payload[0] == 0xE4:
            self.rec.roles[f.number] = ("ended?", ep)
            self._finish(ep, "fault")
        elif isinstance(cmd, MOTION) and resp.ack:
            self._motion(f, cmd, motor, ep, span)
        elif isinstance(cmd, StopMove) and ep is not None and resp.ack:
            self._stop(f, cmd, ep, span)
        elif ep is not None:
            self._other(f, cmd, resp, ep, span)
        else:
            self._at_rest(cmd, resp, motor)

    def _position(self, f: Frame, motor: int, pos: int, ep: Episode | None, span: Span) -> None:
        if ep is None:
            stopped = self.waiting_rest.pop(motor, None)
            if stopped is not None and stopped.stop_tau is not None:
                stopped.rest = Point(f.number, stopped.stop_tau, pos)
                self.rec.roles[f.number] = ("rest", stopped)
            self.rest_pos[motor] = pos
            return
        if ep.stop is None:
            ep.reads.append(Point(f.number, span.since(ep.start), pos))
            self.rec.roles[f.number] = ("moving", ep)
        else:
            self.rec.roles[f.number] = ("after_soft", ep)

    def _motion(self, f: Frame, cmd: Command, motor: int, ep: Episode | None, span: Span) -> None:
        self.waiting_rest.pop(motor, None)
        if ep is None:
            ep = Episode(motor, f, span, self.rest_pos.get(motor))
            self.current[motor] = ep
            self.rec.episodes.append(ep)
            self.rec.roles[f.number] = ("start", ep)
        ep.commands.append(cmd)
        ep.target = self._target(cmd, motor)
        ep.targets.append(ep.target)
        self.rest_pos[motor] = None

    def _target(self, cmd: Command, motor: int) -> int | None:
        if isinstance(cmd, MoveTo):
            return cmd.position
        if isinstance(cmd, InitMove):
            return 0
        if isinstance(cmd, MoveToWayPoint):
            return self.waypoints.get((motor, cmd.waypoint))
        if isinstance(cmd, GoHome):
            return self.home.get(motor)
        return None  # Move: runs until stopped

    def _stop(self, f: Frame, cmd: StopMove, ep: Episode, span: Span) -> None:
        self.rec.roles[f.number] = ("stop", ep)
        if ep.stop is not None:  # a second stop: the first one decided where it went
            if cmd.hard:
                self._finish(ep, "stopped")
            return
        ep.stop, ep.hard, ep.stop_tau = f, cmd.hard, span.since(ep.start)
        if cmd.hard:
            ep.end = _intersect(ep.end, ep.stop_tau)
            self._finish(ep, "stopped")

    def _other(self, f: Frame, cmd: Command, resp: Response, ep: Episode, span: Span) -> None:
        seen = ends(cmd, resp, span, ep.start, self.j)
        if seen is None:
            return
        self.rec.roles[f.number] = ("ended?", ep)
        ep.end = _intersect(ep.end, seen)
        if seen.hi < INF:  # it had ended
            overtaking = self._stop_behind(f, ep.motor) if ep.stop is None else None
            if overtaking is not None:
                stop = overtaking.command
                assert isinstance(stop, StopMove)
                self._stop(overtaking, stop, ep, self.spans[overtaking.number])
            self._finish(ep, "stopped" if ep.stop is not None else "done")
        if isinstance(cmd, SaveWayPoint | SaveHome) and resp.ack:
            self._at_rest(cmd, resp, ep.motor)

    def _stop_behind(self, f: Frame, motor: int) -> Frame | None:
        """A StopMove of ``motor`` held behind ``f`` (a WaitMoved) but executed on arrival,
        before ``f`` was answered (PROTOCOL.md 4): it, not the motion's end, stopped it."""
        assert f.answer is not None
        for g in self.frames[f.number :]:  # the frames after f (numbers count from 1)
            if g.t_ns > f.answer.t_ns:
                return None
            answer = g.answer.response if g.answer is not None else None
            stop = g.command
            if isinstance(stop, StopMove) and stop.motor == motor and answer and answer.ack:
                return g
        return None

    def _finish(self, ep: Episode, how: str) -> None:
        ep.ended = how
        self.current.pop(ep.motor, None)
        if how == "done" and len(ep.commands) == 1:
            self.rest_pos[ep.motor] = ep.target
        else:
            self.rest_pos[ep.motor] = None
            if how == "stopped":
                self.waiting_rest[ep.motor] = ep

    def _at_rest(self, cmd: Command, resp: Response, motor: int) -> None:
        if isinstance(cmd, SaveWayPoint) and resp.ack:
            self.waypoints[(motor, resp.payload[0])] = self.rest_pos.get(motor)
        elif isinstance(cmd, SaveHome) and resp.ack:
            self.home[motor] = self.rest_pos.get(motor)


def recording(conv: Conversation, spans: dict[int, Span], j: float) -> Recording:
    """The recording's motions: episodes from rest to rest and what each frame is to them.

    A motion command's ACK starts one (or joins the running one: queued); IsReady TRUE, a
    WaitMoved's ACK, a SaveHome/SaveWayPoint's ACK, a hard StopMove's ACK or an E4 end it (a
    StopMove that arrived while a WaitMoved was held stopped it, though answered after). At
    the start of the recording motors are taken to be at rest."""
    b = _Builder(conv.frames, spans, j)
    for f in conv.frames:
        b.frame(f)
    return b.rec


# --- bounds ----------------------------------------------------------------------------------


@dataclass
class Speed:
    """The fastest a motion can have moved (step/s), and why."""

    v: float | None
    why: str


def _nominal(cmd: Command) -> float | None:
    if isinstance(cmd, MoveTo | MoveToWayPoint) and cmd.speed:
        return cmd.speed * MOVE_SPEED_FACTOR
    if isinstance(cmd, Move | InitMove) and cmd.speed:
        return cmd.speed * RUN_SPEED_FACTOR
    return None


def known_points(ep: Episode, with_rest: bool = True) -> list[Point]:
    pts = list(ep.reads)
    if with_rest and ep.rest is not None:
        pts.append(ep.rest)
    if ep.ended == "done" and ep.target is not None and ep.end.lo > -INF:
        pts.append(Point(0, ep.end, ep.target))
    return pts


def _fastest_seen(ep: Episode, j: float) -> float:
    """The largest average speed between two known positions of the motion (step/s), each
    time span counted j longer and each distance a step shorter (reads a few ms apart
    would otherwise read a single step as a high speed)."""
    pts = ([Point(ep.first.number, Span(0.0, 0.0), ep.p0)] if ep.p0 is not None else []) + [
        p for p in known_points(ep) if not (ep.stop is not None and not ep.hard and p is ep.rest)
    ]
    best = 0.0
    for a, b in itertools.pairwise(pts):
        dt = b.tau.hi - a.tau.lo + j
        if dt > 0:
            best = max(best, (abs(wrapped(b.pos - a.pos)) - 1) / dt)
    return best


def speed_bound(ep: Episode, tau_max: float, j: float) -> Speed:
    """The fastest the motion of ``ep`` can have moved up to its own time ``tau_max``.

    - its command's SPEED byte times the protocol's factor (a device only clamps lower),
      unless the recording shows it moving faster than that (its [units] differ);
    - for one command from rest: twice its average speed from its start to a position the
      recording knows (a speed that rises, holds and falls covers at least half the distance
      its top speed would), times tau_max / t beyond that position's time t (still rising);
      t is counted from j after its answer (its start may lag that much).
    The smaller of the two; None when neither is known."""
    best: tuple[float, str] | None = None
    nominal = [_nominal(c) for c in ep.commands]
    if all(n is not None for n in nominal):
        v = max(n for n in nominal if n is not None)
        if _fastest_seen(ep, j) <= v:
            best = (v, f"its SPEED byte: {v:.0f} step/s")
    if ep.simple and ep.p0 is not None and ep.direction:
        for p in known_points(ep):
            d = ep.direction * wrapped(p.pos - ep.p0)
            t = p.tau.lo - j
            if d <= 0 or t <= 0:
                continue
            v = 2 * d / t * max(1.0, tau_max / t)
            if best is None or v < best[0]:
                where = f"frame #{p.frame}'s" if p.frame else "its end"
                best = (
                    v,
                    f"twice its average speed up to {where} position "
                    f"({d} steps in {p.tau.lo:.3f} s less {j * 1000:.0f} ms)"
                    + (f", rising till {tau_max:.3f} s" if tau_max > t else ""),
                )
    if best is None:
        return Speed(None, "no speed known (SPEED byte 0 and no position from rest)")
    return Speed(best[0], f"at most {best[0]:.0f} step/s: {best[1]}")


def accel_ratio(ep: Episode) -> tuple[float, str]:
    """How much faster than its speed a soft stop's end point moves while accelerating:
    1 + acc/dec (the command's bytes; the device's defaults taken as equal when 0)."""
    cmd = ep.commands[0]
    acc, dec = getattr(cmd, "acc", 0), getattr(cmd, "dec", 0)
    if acc and dec:
        return 1 + acc / dec, f"1 + ACC/DEC = {1 + acc / dec:.2f}"
    return 2.0, "1 + acc/dec with the device's defaults taken as equal: 2"


def envelope(
    points: Iterable[tuple[Span, float]],
    tau: Span,
    v: float | None,
    j: float,
    start_known: bool,
    cap: float | None,
) -> tuple[float, float]:
    """How far (steps, counted the way it moves, from its start) a one-way motion can be at
    some moment of ``tau`` (its own time) given where it was at other moments (``points``:
    when, how far), at most ``v`` step/s, each moment's timing known to ``j``."""
    lo = 0.0 if start_known else -INF
    hi = INF if v is None or not start_known else v * max(0.0, tau.hi)
    if cap is not None:
        hi = min(hi, cap)
    for when, d in points:
        early = tau.lo - when.hi - j  # > 0: tau is certainly later than `when`
        late = tau.hi - when.lo + j  # < 0: certainly earlier
        if v is None:
            lo = max(lo, d) if early >= 0 else lo
            hi = min(hi, d) if late <= 0 else hi
        else:
            lo = max(lo, d - v * max(0.0, -early))
            hi = min(hi, d + v * max(0.0, late))
    return lo, hi


# --- the replay's side of a motion ---------------------------------------------------------


@dataclass
class Replayed:
    """What the replay did with one recorded episode: its start, offset, stop."""

    start: Span
    offset: int | None  # its start position minus the recording's (None: unknown)
    stop: Span | None = None
    unknown: str = ""  # why the offset is unknown


@dataclass(frozen=True)
class _Frame:
    """A one-way motion seen from its start, counted the way it moves: the recording's
    positions from its start ``ref_r``, the replay's from its own ``ref_p``; ``cap`` how far
    its target is (the replay's), ``start_known``: whether ``ref_r`` is where it started."""

    d: int
    ref_r: int
    ref_p: int
    start_known: bool
    cap: float | None

    def far(self, pos: int) -> float:
        return float(self.d * wrapped(pos - self.ref_r))

    def positions(self, lo: float, hi: float, tol: int) -> tuple[int, int]:
        a, b = self.ref_p + self.d * (lo - tol), self.ref_p + self.d * (hi + tol)
        return _ints(min(a, b), max(a, b))


def _frame_of(ep: Episode, rp: Replayed, tol: int) -> _Frame | Check:
    """How to measure ``ep`` one way from its start, or the judgment when it cannot be."""
    if rp.offset is None:
        return Check(True, f"not judged: where it started here is unknown ({rp.unknown})")
    ref_r = ep.p0 if ep.p0 is not None else 0
    ref_p = ref_r + rp.offset
    d = ep.direction
    if not ep.simple or d == 0:
        return _hull(ep, rp, tol)
    cap: float | None = None
    if ep.target is not None:
        cap = d * wrapped(ep.target - ref_p)
        if ep.p0 is not None and cap < 0:
            return _own_range(ref_p, ep.target, tol)
    return _Frame(d, ref_r, ref_p, ep.p0 is not None, cap)


def _motion_range(
    ep: Episode, m: _Frame, v: float | None, tau: Span, j: float
) -> tuple[float, float]:
    """How far the motion itself can be at ``tau``: from its reads, where a hard stop
    left it, and never beyond where a soft stop brought it to rest."""
    pts = [(p.tau, m.far(p.pos)) for p in ep.reads]
    if ep.hard and ep.rest is not None:
        pts.append((ep.rest.tau, m.far(ep.rest.pos)))
    lo, hi = envelope(pts, tau, v, j, m.start_known, m.cap)
    if not ep.hard and ep.rest is not None and v is not None:
        _, qhi = envelope([(ep.rest.tau, m.far(ep.rest.pos))], tau, v, j, m.start_known, m.cap)
        hi = min(hi, qhi)
    return lo, hi


def _rest_range(
    ep: Episode, m: _Frame, v: float | None, tau: Span, j: float
) -> tuple[float, float]:
    """How far a soft stop taking effect at ``tau`` brings the motion: where the recorded
    soft stop brought it, moving up to ``v`` (already times 1 + acc/dec)."""
    pts = [(ep.rest.tau, m.far(ep.rest.pos))] if ep.rest is not None else []
    return envelope(pts, tau, v, j, m.start_known, m.cap)


def positions(ep: Episode, rp: Replayed, which: str, tau: Span, j: float, tol: int) -> Check:
    """Where the replay's motor may be (its own positions) at ``tau`` (the replay's motion
    time): ``which`` "f" the motion itself, "q" where a soft stop at ``tau`` brings it to
    rest, "after_soft" anywhere between the two."""
    m = _frame_of(ep, rp, tol)
    if isinstance(m, Check):
        return m
    latest = max((p.tau.hi for p in known_points(ep)), default=0.0)
    speed = speed_bound(ep, max(tau.hi, latest) + j, j)
    ratio, ratio_why = accel_ratio(ep)
    vq = None if speed.v is None else speed.v * ratio
    lo, hi = _motion_range(ep, m, speed.v, tau, j) if which != "q" else (0.0, 0.0)
    if which != "f":
        qlo, hi = _rest_range(ep, m, vq, tau, j)
        lo = qlo if which == "q" else lo
    parts = [speed.why]
    if which != "f" and speed.v is not None:
        parts.append(f"where a soft stop ends moves up to {ratio_why} times that")
    if lo > hi:  # the recording's own positions disagree with the bound: order only
        lo, hi = _motion_range(ep, m, None, tau, j)
        parts.append("the recording's positions are further apart than that: by order only")
    return Check(True, "; ".join(parts), allowed=m.positions(lo, hi, tol))


def _ints(lo: float, hi: float) -> tuple[int, int]:
    return (
        POS_MIN if lo == -INF else max(POS_MIN, math.floor(lo)),
        POS_MAX if hi == INF else min(POS_MAX, math.ceil(hi)),
    )


def _hull(ep: Episode, rp: Replayed, tol: int) -> Check:
    """Anywhere between the positions the motion can have reached (its start, its reads,
    its target; the replay's offset added to what was relative to its start): for queued
    motions, homing and unknown directions."""
    off = rp.offset or 0
    known = [p.pos + off for p in ep.reads + ([ep.rest] if ep.rest else [])]
    lo, hi = -INF, INF
    targets = [t for t in ep.targets if t is not None]
    if ep.p0 is not None and len(targets) == len(ep.targets) and not ep.homing:
        known += [*targets, ep.p0 + off]
        lo, hi = min(known) - tol, max(known) + tol
    what = (
        "homing: anywhere on its way to the end stop"
        if ep.homing
        else "more than one motion queued, or its direction unknown: anywhere it could reach"
    )
    return Check(True, what, allowed=_ints(lo, hi))


def _own_range(start: int, target: int, tol: int) -> Check:
    """A motion the recording has no other of (it went the other way here, having started
    elsewhere): between its own start and target."""
    return Check(
        True,
        "it went the other way here (it started elsewhere): between its start and target",
        allowed=_ints(min(start, target) - tol, max(start, target) + tol),
    )


def gap(rec: Span, rep: Span) -> str:
    lo, hi = (rep.lo - rec.hi) * 1000, (rep.hi - rec.lo) * 1000
    return f"{lo:+.1f}..{hi:+.1f} ms"


def end_shift(ep: Episode, rp: Replayed, j: float) -> tuple[Span, str]:
    """How much later (s, its own time) the motion may end in the replay than recorded."""
    if ep.stop is not None and not ep.hard and ep.stop_tau is not None and rp.stop is not None:
        ratio, _ = accel_ratio(ep)
        tau = rp.stop.since(rp.start)
        early = min(0.0, tau.lo - ep.stop_tau.hi - j) * ratio
        late = max(0.0, tau.hi - ep.stop_tau.lo + j) * ratio
        return Span(early, late), f"its soft stop {gap(ep.stop_tau, tau)} from the recorded one"
    if rp.offset:
        if ep.simple and ep.p0 is not None and ep.target is not None and ep.end.hi < INF:
            dist = abs(wrapped(ep.target - ep.p0))
            if dist:
                dt = abs(rp.offset) * ep.end.hi / dist
                return Span(-dt, dt), f"it started {rp.offset:+d} steps from the recorded start"
        return Span(-INF, INF), "it started elsewhere (an earlier stop)"
    return Span(0.0, 0.0), ""
