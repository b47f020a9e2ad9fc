"""What a recording says of its motions (docs/trace.md, "How the answers are judged"): the
half of the replay's judge that reads the recording's motions;
:mod:`motorctl.client.motion_bounds` bounds where each could have been at a moment of the
replay, :mod:`motorctl.client.judge` judges the answers with both.

A motion (an :class:`Episode`) runs from rest to rest; the recording's answers say when it
started and ended, where it was at some of its moments (its reads, where a stop left it),
when it ended. Moments are windows (:class:`Span`: a command took effect at one moment
between sending its frame and receiving its answer) counted from the motion's command.

Pure computation; runs on the caller's thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from motorctl.client.conversation import Conversation, Frame
from motorctl.protocol.codec import (
    POS_MAX,
    POS_MIN,
    Command,
    GetAbsPos,
    IsReady,
    Response,
    SaveHome,
    SaveWayPoint,
    StopMove,
    WaitMoved,
)
from motorctl.protocol.spec import Motion

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
        return len(self.commands) == 1 and not motion(self.commands[0]).homes

    @property
    def homing(self) -> bool:
        return any(motion(c).homes for c in self.commands)

    @property
    def direction(self) -> int:
        """+1 counting up, -1 down, 0 unknown (or more than one command)."""
        if len(self.commands) != 1:
            return 0
        cmd = self.commands[0]
        if motion(cmd).in_direction:
            return 1 if getattr(cmd, "direction", True) else -1
        if self.target is not None and self.p0 is not None:
            return _sign(wrapped(self.target - self.p0))
        known = [p.pos for p in self.reads] + ([self.rest.pos] if self.rest else [])
        if self.p0 is not None:
            known.insert(0, self.p0)
        return _sign(wrapped(known[-1] - known[0])) if len(known) >= 2 else 0


def motion(cmd: Command) -> Motion:
    """What the command table says of a motion command's motion (which commands move, where
    each ends, which way it runs: protocol/commands.py)."""
    m = cmd.spec.motion
    if m is None:
        raise ValueError(f"{cmd.spec.name} is not a motion command")
    return m


def _sign(x: float) -> int:
    return (x > 0) - (x < 0)


@dataclass
class RecordedMotions:
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
        self.rec = RecordedMotions()
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
        elif cmd.spec.motion is not None and resp.ack:
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
        """Where ``cmd`` ends when it runs to its end (None: unknown, or it runs until
        stopped), as the table's ``motion.ends`` says."""
        ends = motion(cmd).ends
        if ends == "zero":
            return 0
        if ends == "waypoint":
            return self.waypoints.get((motor, getattr(cmd, "waypoint")))  # noqa: B009
        if ends == "home":
            return self.home.get(motor)
        if ends:
            value = getattr(cmd, ends)
            return value if isinstance(value, int) else None
        return None  # it runs until stopped

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


def recording(conv: Conversation, spans: dict[int, Span], j: float) -> RecordedMotions:
    """The recording's motions: episodes from rest to rest and what each frame is to them.

    A motion command's ACK starts one (or joins the running one: queued); IsReady TRUE, a
    WaitMoved's ACK, a SaveHome/SaveWayPoint's ACK, a hard StopMove's ACK or an E4 end it (a
    StopMove that arrived while a WaitMoved was held stopped it, though answered after). At
    the start of the recording motors are taken to be at rest."""
    b = _Builder(conv.frames, spans, j)
    for f in conv.frames:
        b.frame(f)
    return b.rec
