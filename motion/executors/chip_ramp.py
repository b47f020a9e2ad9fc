"""The executor for driver chips that run their own ramps.

:class:`RampExecutor` carries out the motors' plans with each driver's own ramp generator,
through the HAL's :class:`~motorctl.hal.interfaces.RampDriver` capability (a TMC5160 in
motion-controller mode, a dSPIN): a finite plan (MoveTo, a soft stop, a homing back-off, a run up to
a soft limit) becomes a trapezoid to the plan's end at the plan's peak speed with its ramps
(``move_to``); an endless run becomes ``run`` at its speed. A hard stop is ``stop(None)``:
the chip's largest deceleration. Positions are the chip's step counter. End stops are the
chip's reference switches: the one ahead stops the motor in the chip and latches the
position, reported as ENDSTOP at the latched position; a motion toward a switch that the
read it starts from (``committed()``) finds active already is not handed to the chip at all:
ENDSTOP at once where the motor stands, "already active" (a dSPIN's SW stops the motor only
as it closes: one closed already would let a GoTo_DIR run on into the machine's end);
homing's back-off (a plan followed with ``release``) has the switch behind latch the
position where it releases, and once a poll sees it released the executor stops the chip
(its hard stop) and reports RELEASED with that latched position; stall homing (a plan
without end stops) lets stallGuard stop the motor, and that stop is reported as the
driver's stall flag. A finite plan is done when the chip stands at its end, or stands where
it settled on purpose (``RampStatus.settled``: a dSPIN takes no new target while it ramps
and stops along DEC instead); an endless run is done where its chip settled it (a dSPIN's
run at the end of ABS_POS's range).
:meth:`RampExecutor.committed`, which the engine plans a motion from just before it hands
it to :meth:`RampExecutor.follow`, reads the chip with ``command_status``: the one read
that the ``watch`` and the command after it may build on (a dSPIN's MoveTo then reads
STATUS and ABS_POS once, not three and two times).

A machine that mixes such motors with STEP/DIR ones runs both executors behind one seam
(``split.py``).

Threads: as every :class:`~motorctl.motion.executors.base.Executor`: commands and
:meth:`service` come with the engine's lock held (the planner thread); the drivers' bus
transfers happen there (a few SPI datagrams, tens of microseconds each) and never on a step
path. :meth:`position`, :meth:`endstop_active` and :meth:`health` read snapshots that
:meth:`service` refreshes. Driver failures become FAULT events (the axis stops, its
position is lost): never an exception out of the seam, never a dead thread.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass

from motorctl.hal.interfaces import Clock, HalError, RampDriver, RampStatus
from motorctl.motion.executors.base import (
    ENDSTOP_ALREADY_ACTIVE,
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
    ExecutorHealth,
)
from motorctl.motion.profile import Trajectory
from motorctl.motion.types import Ramp

log = logging.getLogger("motorctl.ramp")

K = ExecEventKind


@dataclass
class _Axis:
    """One axis on its chip's ramp generator: the plan asked of it, the switch armed to stop
    it, and what the chip said last."""

    gen: int = 0
    plan: str = ""  # "move", "run", "stop" or "" (nothing planned)
    target: int = 0
    watch: int = 0  # the stop switch armed: +1 REFR, -1 REFL, 0 none
    release: int = 0  # the switch whose release ends the plan: +1 REFR, -1 REFL, 0 none
    stop_gen: int = 0
    blocked: bool = False  # stopped on its own: plans dropped until the caller's stop()
    position: int = 0
    velocity: float = 0.0  # steps/s
    status: RampStatus | None = None  # the last read
    next_poll: float = 0.0
    resets: int = 0  # chip resets already reported


def peak_speed(traj: Trajectory) -> float:
    """The largest speed a (finite) trajectory reaches."""
    best = 0.0
    for seg in traj.segments:
        best = max(best, abs(seg.v0), abs(seg.end_velocity))
    return best


class RampExecutor(Executor):
    """Motors whose driver chip moves them (:class:`RampDriver`): one chip per motor."""

    def __init__(
        self,
        chips: Sequence[RampDriver],
        clock: Clock,
        poll_s: float = RampDriver.poll_s,
        idle_poll_s: float = RampDriver.idle_poll_s,
    ) -> None:
        super().__init__(len(chips))
        self.chips = list(chips)
        self.clock = clock
        self.poll_s = poll_s
        self.idle_poll_s = idle_poll_s
        self._axes = [_Axis() for _ in chips]
        self._events: list[ExecEvent] = []
        self._lock = threading.Lock()
        self._progress = 0
        self.counters = {"polls": 0, "spi_errors": 0, "endstops": 0, "sg_stops": 0}
        for i, chip in enumerate(self.chips):  # the counters are XACTUAL from the start:
            with suppress(HalError):  # the daemon restores positions before start()
                self._refresh(i, chip.ramp_status())

    # -- lifecycle -----------------------------------------------------------------
    def start(self) -> None:
        now = self.clock.now()
        for i, chip in enumerate(self.chips):
            try:
                self._refresh(i, chip.ramp_status())
            except HalError as exc:
                self._fault(i, now, exc)

    def close(self) -> None:
        for i, chip in enumerate(self.chips):
            try:
                chip.stop(None)
            except HalError as exc:
                log.error("motor %d: could not stop the ramp at close: %s", i, exc)

    # -- events ------------------------------------------------------------------------
    def _emit(self, ev: ExecEvent) -> None:
        with self._lock:
            self._events.append(ev)
        self.on_event()

    def events(self) -> list[ExecEvent]:
        with self._lock:
            out, self._events = self._events, []
        return out

    def events_waiting(self) -> bool:
        """The list holds an event (appended under ``_lock``; its length is read whole)."""
        return bool(self._events)

    def _fault(self, motor: int, now: float, exc: BaseException) -> None:
        ax = self._axes[motor]
        self.counters["spi_errors"] += 1
        ax.plan, ax.blocked = "", True
        with suppress(HalError):
            self.chips[motor].stop(None)
        # as for a failed STEP line: the position counts as lost if it was moving fast
        self._emit(
            ExecEvent(
                K.FAULT, motor, ax.gen, ax.position, now, speed=abs(ax.velocity), detail=str(exc)
            )
        )

    # -- commands ------------------------------------------------------------------------
    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        ax, chip = self._axes[motor], self.chips[motor]
        if ax.blocked:
            return True  # made before the caller saw our event: dropped, as the seam says
        now = self.clock.now()
        ax.gen = gen
        run = math.isinf(traj.end_time)
        v = traj.segments[-1].v0 if run else 0.0
        target = 0 if run else round(traj.end_position)
        if not run and target == ax.position and ax.velocity == 0:
            ax.plan = ""
            return False
        direction = (1 if v > 0 else -1) if run else (1 if target > ax.position else -1)
        ahead, behind = direction if endstops else 0, -direction if release else 0
        if ahead and ax.status is not None and ax.status.switch_active(ahead):
            # committed()'s read: on it already. Not handed to the chip (a dSPIN's switch
            # stops a motor only as it closes, and one closed already would let it run on
            # into the machine's end): at once where it stands, as the step cores do
            self._endstop(motor, ax, ahead, ax.position, now, ENDSTOP_ALREADY_ACTIVE)
            return True
        try:
            chip.watch(ahead, stall=not endstops, release=behind)
            if run:
                chip.run(direction, abs(v), ramp.acc)
                ax.plan = "run"
            else:
                speed = max(peak_speed(traj), abs(ax.velocity), 1.0)
                chip.move_to(target, speed, ramp.acc, ramp.dec)
                ax.plan, ax.target = "move", target
            ax.watch, ax.release = ahead, behind
        except HalError as exc:
            self._fault(motor, now, exc)
            return True
        # the first read a poll period on: the chip has only just been given the motion (a
        # read at once would find nothing new, and only contend with the command's answer)
        ax.next_poll = now + self.poll_s
        return True

    def _endstop(
        self, motor: int, ax: _Axis, ahead: int, where: int, now: float, detail: str
    ) -> None:
        """The reference switch ahead (``ahead``) stopped the motor at ``where``, or it stood
        on it already (``detail`` :data:`ENDSTOP_ALREADY_ACTIVE`): ENDSTOP, the axis blocked
        until its stop."""
        self.counters["endstops"] += 1
        ax.plan, ax.blocked = "", True
        ev = ExecEvent(K.ENDSTOP, motor, ax.gen, where, now, ahead, abs(ax.velocity), detail=detail)
        self._emit(ev)

    def stop(self, motor: int, gen: int) -> int | None:
        ax = self._axes[motor]
        ax.blocked = False
        ax.stop_gen = ax.gen = gen
        try:
            self.chips[motor].stop(None)
        except HalError as exc:
            # answering with another event would make the caller stop again, and again:
            # the last known position is final; the driver monitor reports the SPI failure
            self.counters["spi_errors"] += 1
            log.error("motor %d: the hard stop did not reach the chip: %s", motor, exc)
            ax.plan = ""
            return ax.position
        ax.plan = "stop"
        ax.next_poll = self.clock.now()
        return None

    def committed(self, motor: int, now: float) -> Committed:
        ax = self._axes[motor]
        with suppress(HalError):  # the snapshot will do; the next poll reports the failure
            # the read that the follow() after it (the engine's next plan) builds on
            self._refresh(motor, self.chips[motor].command_status())
        return Committed(now, float(ax.position), ax.velocity, ax.position)

    def planned(self, motor: int) -> bool:
        return self._axes[motor].plan != ""

    # -- the planner's side ----------------------------------------------------------------
    def _refresh(self, motor: int, st: RampStatus) -> None:
        ax = self._axes[motor]
        ax.position = st.position
        ax.velocity = st.velocity
        ax.status = st

    def service(self, now: float) -> float:
        self._progress += 1
        nxt = now + self.idle_poll_s
        for i, (ax, chip) in enumerate(zip(self._axes, self.chips, strict=True)):
            if now >= ax.next_poll:
                ax.next_poll = now + (self.poll_s if ax.plan else self.idle_poll_s)
                self._poll(i, ax, chip, now)
            nxt = min(nxt, ax.next_poll)
        return nxt

    def _poll(self, i: int, ax: _Axis, chip: RampDriver, now: float) -> None:
        self.counters["polls"] += 1
        try:
            st = chip.ramp_status()
        except HalError as exc:
            if ax.plan:
                self._fault(i, now, exc)
            return
        self._refresh(i, st)
        if chip.resets != ax.resets:  # XACTUAL restarted at 0: the position is lost
            ax.resets = chip.resets
            ax.plan, ax.blocked = "", True
            self._emit(
                ExecEvent(
                    K.FAULT,
                    i,
                    ax.gen,
                    ax.position,
                    now,
                    speed=math.inf,
                    detail=f"{chip.name}: the driver was reset; position lost",
                )
            )
            return
        if st.stall_stopped and chip.report_stall_stop():  # the driver's stall flag: the
            self.counters["sg_stops"] += 1  # engine's driver monitor acts on it
        if ax.plan == "stop":
            if st.velocity == 0:
                ax.plan = ""
                self._emit(ExecEvent(K.STOPPED, i, ax.stop_gen, ax.position, now))
            return
        if ax.plan == "" or ax.blocked:
            return
        if ax.watch and st.switch_stopped(ax.watch):
            where = ax.position
            if st.latched(ax.watch):
                try:
                    where = chip.latched_position()
                except HalError as exc:
                    self._fault(i, now, exc)
                    return
            self._endstop(i, ax, ax.watch, where, now, "reference switch")
            return
        if ax.release and (st.latched(ax.release) or not st.switch_active(ax.release)):
            self._released(i, ax, chip, st, now)
            return
        done = ax.position == ax.target if ax.plan == "move" else False
        if st.velocity == 0 and (done or st.settled):  # a run settles where its chip's
            ax.plan = ""  # counter ends (a dSPIN's ABS_POS): done there, as at a soft limit
            self._emit(ExecEvent(K.DONE, i, ax.gen, ax.position, now))

    def _released(self, i: int, ax: _Axis, chip: RampDriver, st: RampStatus, now: float) -> None:
        """The switch behind released: stop the chip (hard) and report where (its latch;
        without one, the switch read inactive already: where the chip is)."""
        try:
            where = chip.latched_position() if st.latched(ax.release) else ax.position
            chip.stop(None)
        except HalError as exc:
            self._fault(i, now, exc)
            return
        ax.plan, ax.blocked = "", True
        self._emit(
            ExecEvent(
                K.RELEASED,
                i,
                ax.gen,
                ax.position,
                now,
                direction=ax.release,
                speed=abs(ax.velocity),
                detail="reference switch",
                mark=where,
            )
        )

    # -- snapshots ----------------------------------------------------------------------------
    def position(self, motor: int) -> int:
        return self._axes[motor].position

    def endstop_active(self, motor: int, direction: int) -> bool:
        st = self._axes[motor].status
        return st is not None and st.switch_active(direction)

    @property
    def times_steps(self) -> bool:
        """False: the chips make their motors' steps, on their own ramps."""
        return False

    def health(self) -> ExecutorHealth:
        return ExecutorHealth(alive=True, progress=self._progress, counters=dict(self.counters))

    # -- a virtual clock: the polls are due in service() -----------------------------------------
    def next_deadline(self) -> float | None:
        return min(ax.next_poll for ax in self._axes) if self._axes else None

    def advance(self, now: float) -> None:
        return None
