"""How ``motorctl replay`` judges the device's answers against a recording's (docs/trace.md,
"How answers are judged").

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

Where a judgment fails, the replay's pacing is looked at: if the replay sent the frames that
judgment depends on later than ``j`` after they were due, and the answer fits with ``j``
widened to that, the verdict is ``pacing`` (the replay could not keep the timing the
tolerance assumes), not ``differs``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from motorctl.client.trace import ANSWER, Conversation, Frame, Row, answer_text
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
    describe,
)

TIME_TOLERANCE_S = 0.05
POSITION_TOLERANCE = 2
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

    def widened(self, by: float) -> Span:
        return Span(self.lo - by, self.hi + by)

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


# --- verdicts --------------------------------------------------------------------------------


@dataclass
class Tolerances:
    time_s: float = TIME_TOLERANCE_S
    position: int = POSITION_TOLERANCE


@dataclass
class Verdict:
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
    end_seen: bool = False
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


#: what a frame is to the judge: (role, its episode)
ROLES = (
    "start",  # the motion command that started an episode
    "moving",  # a position read while it moved, before any stop
    "after_soft",  # a position read after its soft stop, maybe still moving
    "rest",  # the first position read at rest after a stop
    "ended?",  # an answer that depends on whether it had ended
    "stop",  # its StopMove
)


@dataclass
class Recording:
    episodes: list[Episode] = field(default_factory=list)
    roles: dict[int, tuple[str, Episode]] = field(default_factory=dict)
    holds: set[int] = field(default_factory=set)  # WaitMoved frames: answered when it stood


def _ends(cmd: Command, resp: Response, span: Span, start: Span, j: float) -> Span | None:
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
    if isinstance(cmd, StopMove) and cmd.hard and resp.ack:
        return Span(lo, hi)
    return None


def _intersect(a: Span, b: Span) -> Span:
    return Span(max(a.lo, b.lo), min(a.hi, b.hi))


class _Builder:
    """Reads the recording's answers in order into episodes (:func:`recording`)."""

    def __init__(self, spans: dict[int, Span], j: float) -> None:
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
        seen = _ends(cmd, resp, span, ep.start, self.j)
        if seen is None:
            return
        self.rec.roles[f.number] = ("ended?", ep)
        ep.end = _intersect(ep.end, seen)
        ep.end_seen = True
        if seen.hi < INF:  # it had ended
            self._finish(ep, "stopped" if ep.stop is not None else "done")
        if isinstance(cmd, SaveWayPoint | SaveHome) and resp.ack:
            self._at_rest(cmd, resp, ep.motor)

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
    WaitMoved's ACK, a SaveHome/SaveWayPoint's ACK, a hard StopMove's ACK or an E4 end it. At
    the start of the recording motors are taken to be at rest."""
    b = _Builder(spans, j)
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


def _known_points(ep: Episode, with_rest: bool = True) -> list[Point]:
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
        p for p in _known_points(ep) if not (ep.stop is not None and not ep.hard and p is ep.rest)
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
        for p in _known_points(ep):
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


def _accel_ratio(ep: Episode) -> tuple[float, str]:
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


# --- the replay's side -----------------------------------------------------------------------


@dataclass
class Replayed:
    """What the replay did with one recorded episode: its start, offset, stop."""

    start: Span
    offset: int | None  # its start position minus the recording's (None: unknown)
    stop: Span | None = None
    unknown: str = ""  # why the offset is unknown


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


def _positions(ep: Episode, rp: Replayed, which: str, tau: Span, j: float, tol: int) -> Check:
    """Where the replay's motor may be (its own positions) at ``tau`` (the replay's motion
    time): ``which`` "f" the motion itself, "q" where a soft stop at ``tau`` brings it to
    rest, "after_soft" anywhere between the two."""
    m = _frame_of(ep, rp, tol)
    if isinstance(m, Check):
        return m
    latest = max((p.tau.hi for p in _known_points(ep)), default=0.0)
    speed = speed_bound(ep, max(tau.hi, latest) + j, j)
    ratio, ratio_why = _accel_ratio(ep)
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


def _gap(rec: Span, rep: Span) -> str:
    lo, hi = (rep.lo - rec.hi) * 1000, (rep.hi - rec.lo) * 1000
    return f"{lo:+.1f}..{hi:+.1f} ms"


def judge_position(f: Frame, role: str, ep: Episode, b: Row, ctx: Context, j: float) -> Check:
    """A position that timing decides (role "moving", "after_soft", "rest")."""
    assert f.answer is not None
    rp = ctx.episodes[ep.first.number]
    pa, pb = _frame_pos(f.answer), _frame_pos(b)
    tol = ctx.tol.position
    if role == "moving":
        tau = ctx.rep_spans[f.number].since(rp.start)
        rec_tau = ctx.rec_spans[f.number].since(ep.start)
        check = _positions(ep, rp, "f", tau, j, tol)
        what = f"read while moving, {_gap(rec_tau, tau)} from the recorded read in its time"
    elif rp.stop is None or ep.stop_tau is None:
        return Check(False, "its stop was not answered in the replay")
    else:
        tau = rp.stop.since(rp.start)
        which = "after_soft" if role == "after_soft" else ("f" if ep.hard else "q")
        check = _positions(ep, rp, which, tau, j, tol)
        kind = "hard" if ep.hard else "soft"
        assert ep.stop is not None
        what = (
            f"after the {kind} stop at frame #{ep.stop.number}, which took effect "
            f"{_gap(ep.stop_tau, tau)} from the recorded one in the motion's time"
        )
    if check.allowed is None:
        return Check(True, f"{what}; {check.why}", off=pb - pa)
    lo, hi = check.allowed
    fits = lo <= pb <= hi
    return Check(
        fits,
        f"{what}: {abs(wrapped(pb - pa))} steps from the recorded; "
        f"{'allowed' if fits else 'outside'} {lo}..{hi} ({check.why}; "
        f"device timing +-{j * 1000:.0f} ms, +-{tol} steps)",
        off=wrapped(pb - pa),
        allowed=check.allowed,
    )


def _end_shift(ep: Episode, rp: Replayed, j: float) -> tuple[Span, str]:
    """How much later (s, its own time) the motion may end in the replay than recorded."""
    if ep.stop is not None and not ep.hard and ep.stop_tau is not None and rp.stop is not None:
        ratio, _ = _accel_ratio(ep)
        tau = rp.stop.since(rp.start)
        early = min(0.0, tau.lo - ep.stop_tau.hi - j) * ratio
        late = max(0.0, tau.hi - ep.stop_tau.lo + j) * ratio
        return Span(early, late), f"its soft stop {_gap(ep.stop_tau, tau)} from the recorded one"
    if rp.offset:
        if ep.simple and ep.p0 is not None and ep.target is not None and ep.end.hi < INF:
            dist = abs(wrapped(ep.target - ep.p0))
            if dist:
                dt = abs(rp.offset) * ep.end.hi / dist
                return Span(-dt, dt), f"it started {rp.offset:+d} steps from the recorded start"
        return Span(-INF, INF), "it started elsewhere (an earlier stop)"
    return Span(0.0, 0.0), ""


def judge_end(f: Frame, ep: Episode, b: Row, ctx: Context, j: float) -> Check:
    """An answer that says whether the motion had ended, against when it ended recorded."""
    rp = ctx.episodes[ep.first.number]
    cmd = f.command
    assert cmd is not None and b.response is not None
    seen = _ends(cmd, b.response, ctx.rep_spans[f.number], rp.start, j)
    shift, shift_why = _end_shift(ep, rp, j)
    expect = Span(ep.end.lo + shift.lo - j, ep.end.hi + shift.hi + j)
    said = answer_text(cmd, b.response)
    if seen is None:
        return Check(False, f"{said}: says nothing of the motion's end")
    fits = seen.meets(expect)
    because = f"; {shift_why}" if shift_why else ""
    return Check(
        fits,
        f"{said}: its end here {seen.text()} into the motion, recorded {ep.end.text()}; "
        f"{'allowed' if fits else 'outside'} {expect.text()} (device timing "
        f"+-{j * 1000:.0f} ms{because})",
    )


# --- the comparison --------------------------------------------------------------------------


def _show(row: Row | None, f: Frame | None) -> str:
    if row is None:
        return "no answer"
    text = answer_text(f.command if f else None, row.response) if row.response else row.text
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
        """The judgment of an answer timing decides; None for the others."""
        j = self.ctx.tol.time_s if j is None else j
        if ep is None or f.number not in self.ctx.rep_spans:
            return None
        if ep.first.number not in self.ctx.episodes:  # its start was not answered here
            return None
        if role in ("moving", "after_soft", "rest") and _both_ack(a, b):
            return judge_position(f, role, ep, b, self.ctx, j)
        if role == "ended?" and b.response is not None:
            held = isinstance(f.command, WaitMoved) and _both_ack(a, b)
            if a.data == b.data and not held:
                return None
            return judge_end(f, ep, b, self.ctx, j)
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
        if isinstance(cmd, MoveToWayPoint):
            return self.ctx.waypoints.get((ep.motor, cmd.waypoint), 0)
        if isinstance(cmd, GoHome):
            return self.ctx.home.get(ep.motor, 0)
        return 0  # MoveTo, InitMove (Move never ends by itself)

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


__all__ = [
    "POSITION_TOLERANCE",
    "TIME_TOLERANCE_S",
    "Span",
    "Tolerances",
    "Verdict",
    "compare",
    "envelope",
    "recording",
    "speed_bound",
    "windows",
]
