"""Where a motion of the recording could have been at a moment of the replay (docs/trace.md,
"How the answers are judged"): :func:`positions` bounds where the same motion may be; it
moves one way, at most :func:`speed_bound` step/s; the device's own timing may differ by
``j``. The motions themselves are read by :mod:`motorctl.client.motions`; the judgment is
:mod:`motorctl.client.judge`'s.

The bounds are one derivation with the motions' reading (docs/trace.md writes it out).

Pure computation; runs on the caller's thread.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass

from motorctl.client.motions import INF, Episode, Point, Span, wrapped
from motorctl.protocol.codec import POS_MAX, POS_MIN, Command


@dataclass
class Check:
    """One timing judgment: does the replay's answer fit, and the sentence saying why."""

    fits: bool
    why: str
    off: int | None = None
    allowed: tuple[int, int] | None = None


# --- bounds ----------------------------------------------------------------------------------


@dataclass
class Speed:
    """The fastest a motion can have moved (step/s), and why."""

    v: float | None
    why: str


def _nominal(cmd: Command) -> float | None:
    """The speed a motion command asks for (step/s), by the protocol's unit factor the
    command table names for its SPEED (PROTOCOL.md section 3; a device's [units] may differ,
    which the recording then shows: see :func:`speed_bound`); None: its default."""
    p = cmd.spec.param("speed")
    speed = getattr(cmd, "speed", 0)
    if p is None or p.scale is None or not speed:
        return None
    return float(speed * p.scale.default)


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


def positions(
    ep: Episode, rp: Replayed, which: str, tau: Span, j: float, tol: int, j0: float | None = None
) -> Check:
    """Where the replay's motor may be (its own positions) at ``tau`` (the replay's motion
    time): ``which`` "f" the motion itself, "q" where a soft stop at ``tau`` brings it to
    rest, "after_soft" anywhere between the two. ``j``: the device timing that widens every
    comparison of two moments (a slide included); ``j0`` (default ``j``): the time tolerance
    alone, by which the recorded motion's start may lag its answer (the speed bound)."""
    m = _frame_of(ep, rp, tol)
    if isinstance(m, Check):
        return m
    latest = max((p.tau.hi for p in known_points(ep)), default=0.0)
    speed = speed_bound(ep, max(tau.hi, latest) + j, j if j0 is None else j0)
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
