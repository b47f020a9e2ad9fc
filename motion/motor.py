"""One stepper motor: state machine, motion queue, homing, limits, faults.

Positions: ``abs_steps`` is an unbounded count of the steps emitted since start;
the host's position is ``abs_steps - offset`` mapped by ``params.host_position`` (linear
axis; the daemon passes the protocol's 24-bit wrap) or taken modulo ``steps_per_rev``
(rotary axis). Trajectories are planned in
``abs_steps`` coordinates, so wrapping never reaches the profile math.

Homing (InitMove, docs/protocol.md): run toward the end stop until it triggers (with
``pull_off``: back off that far, re-approach at ``second_speed``), then back off at
``second_speed`` until it releases (the executor stops there and says where: RELEASED) and
make that position 0, so that a MoveTo 0 never touches the switch; at most ``max_travel``
steps each way. Stall homing makes 0 where the motor stalled.

Owner: the motion engine's lock; every method is called with it held (dispatcher, planner
thread, driver monitor). The step path never takes it: motion goes to the executor as
plans, and what the executor did comes back as events (:meth:`Motor.on_event`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from functools import partial

from motorctl.hal.interfaces import DriverStatus, StepperDriver
from motorctl.motion.executors.base import (
    ENDSTOP_ALREADY_ACTIVE,
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
)
from motorctl.motion.profile import Trajectory, plan_move_to, plan_run, plan_stop
from motorctl.motion.types import (
    HomeCmd,
    HomingPhase,
    HomingSource,
    MotionCmd,
    MotorParams,
    MotorState,
    MoveToCmd,
    Ramp,
    RunCmd,
)

K = ExecEventKind


class Motor:
    def __init__(
        self,
        index: int,
        params: MotorParams,
        driver: StepperDriver,
        executor: Executor,
        notify: Callable[[Motor, str], None],
    ) -> None:
        self.index = index
        self.params = params
        self.driver = driver
        self.executor = executor
        self._notify = notify
        self.state = MotorState.IDLE
        self.queue: deque[MotionCmd] = deque()
        self.offset = 0
        self.home = 0
        self.waypoints: list[int] = []
        self.fault: str | None = None
        self.fault_cause: str | None = None  # what the latched fault is counted under
        self.position_lost = False
        self.traj: Trajectory | None = None
        self.gen = 0
        self._awaiting: int | None = None  # a hard stop's generation, until it took effect
        self.stops_settled = 0  # how often a stop that was awaited took effect (or was moot)
        self._then: Callable[[float], None] | None = None
        self._ramp = Ramp(1.0, 1.0, 1.0)
        self._phase: HomingPhase | None = None  # while homing
        # the step counter when the motor last started from rest: a stall flag read before
        # it stepped again is the last motion's (a driver measures stalls only while the
        # motor steps; right after stall homing it may still say so)
        self._started_at = 0
        self._home_cmd: HomeCmd | None = None
        self.faults: dict[str, int] = {}  # faults latched, by cause
        # soft StopMoves: how long after the command, and how many steps on, the deceleration
        # took over (the steps already handed to the executor are still made)
        self.soft_stops = 0
        self.takeover_s = (0.0, 0.0)  # last, max
        self.takeover_steps = (0, 0)  # last, max

    @property
    def abs_steps(self) -> int:
        """The executed step counter (the executor's snapshot)."""
        return self.executor.position(self.index)

    # -- what the host sees -------------------------------------------------
    @property
    def position(self) -> int:
        return self._host(self.abs_steps)

    def set_position(self, position: int) -> None:
        """Declare the current physical position to be ``position`` (homing, restore)."""
        self.offset = self.abs_steps - position

    @property
    def idle(self) -> bool:
        return self.state is MotorState.IDLE and not self.queue and self._awaiting is None

    @property
    def stopping(self) -> bool:
        """A hard stop was asked for and has not yet taken effect in the executor."""
        return self._awaiting is not None

    @property
    def active(self) -> bool:
        return self.state in (
            MotorState.MOVING,
            MotorState.RUNNING,
            MotorState.HOMING,
            MotorState.STOPPING,
        )

    @property
    def queue_full(self) -> bool:
        """True when a command submitted now would not fit behind the running one."""
        if self.idle:
            return False
        return len(self.queue) >= self.params.queue_depth

    def target_allowed(self, target: int) -> bool:
        p = self.params
        if p.soft_min is None or p.soft_max is None or p.rotary:
            return True
        return p.soft_min <= target <= p.soft_max

    def counted_range(self) -> tuple[int, int] | None:
        """The targets (host positions) the driver's own counter can reach from where the
        motor's zero is now (``MotorParams.counter_range``); None: any (the steps are counted
        here, or the driver counts on past its counter's range, as a dSPIN's on a rotary
        axis)."""
        r = self.params.counter_range
        if r is None:
            return None
        return r[0] - self.offset, r[1] - self.offset

    # -- commands -----------------------------------------------------------
    def submit(self, cmd: MotionCmd, now: float) -> None:
        """Queue a motion command (the caller checked faults and queue space)."""
        if self.idle:
            self._start(cmd, now)
        elif (
            isinstance(cmd, RunCmd)
            and self.state is MotorState.RUNNING
            and not self.queue
            and self._awaiting is None
        ):
            self._start(cmd, now)  # a Move while running: change at once along the ramps
        else:
            self.queue.append(cmd)

    def stop(self, hard: bool, now: float) -> bool:
        """StopMove: empty the queue, stop; clear a latched fault if the driver allows.

        Returns False when a latched fault remains (the driver still reports one).
        """
        self.queue.clear()
        if self.fault is not None and self.state is not MotorState.FAULT:
            # latched by fault_stop while still ramping down: this StopMove clears it and
            # takes the stop over (below), as it would for the motor at rest
            self.fault = self.fault_cause = None
            self._notify(self, "cleared")
        if self.state is MotorState.FAULT:
            if self.driver.status().fault is not None:
                return False
            self.fault = self.fault_cause = None
            self.state = MotorState.IDLE
            self._notify(self, "cleared")
            return True
        if not self.active:
            return True
        if hard or self.traj is None:
            self._hard_stop(now, self._become_idle)
        else:
            c = self.executor.committed(self.index, now)
            steps = abs(c.counter - self.abs_steps)
            self.soft_stops += 1
            self.takeover_s = (c.after, max(self.takeover_s[1], c.after))
            self.takeover_steps = (steps, max(self.takeover_steps[1], steps))
            self._follow(
                plan_stop(c.t, c.position, c.velocity, self._ramp.dec), MotorState.STOPPING, now
            )
        return True

    def latch_fault(
        self,
        reason: str,
        now: float,
        *,
        lost: bool = False,
        stopped: bool = False,
        cause: str = "other",
    ) -> None:
        """Stop at once and latch a fault: every command but StopMove/GetAbsPos gets E4.

        ``cause``: what the fault is counted under (``faults``, in the status).

        ``stopped``: the executor already stopped the axis itself and was answered, so the
        position is final now (a StopMove right after makes the motor ready at once).
        """
        self.queue.clear()
        self.fault = reason
        self.fault_cause = cause
        self.faults[cause] = self.faults.get(cause, 0) + 1
        self.state = MotorState.FAULT
        self._phase = None
        self._home_cmd = None
        if lost:
            self.position_lost = True
        if stopped:
            self.traj = None
            self._settled()
            self._then = None
        else:
            self._hard_stop(now, lambda t: None)
        self._notify(self, "fault")

    def fault_stop(self, reason: str, now: float, *, hard: bool, cause: str = "other") -> bool:
        """Stop a motor in motion and latch ``reason`` (E4 from now on until StopMove);
        False, and nothing done, when it was not moving. For a cause outside the motor and
        its executor: the host fell silent (the daemon's ``[link] timeout_ms``).

        ``hard``: at once, as :meth:`latch_fault`. Otherwise along the ramp, as a soft
        StopMove: the fault is latched at once, the motor keeps stopping and is in state
        FAULT once at rest; a StopMove meanwhile clears the fault and takes the stop over.
        A motor with a fault latched already is left as it is.
        """
        if self.fault is not None or not (self.active or self.stopping):
            return False
        if hard:
            self.latch_fault(reason, now, cause=cause)
            return True
        self.stop(hard=False, now=now)
        self.fault = reason
        self.fault_cause = cause
        self.faults[cause] = self.faults.get(cause, 0) + 1
        if not (self.active or self.stopping):  # it stopped at once (nothing to ramp down)
            self.state = MotorState.FAULT
        self._notify(self, "fault")
        return True

    # -- what the executor reports (engine lock held) --------------------------
    def on_event(self, ev: ExecEvent, now: float) -> None:
        k = ev.kind
        if k is K.STOPPED:
            if ev.gen == self._awaiting:
                self._settled()
                then, self._then = self._then, None
                if then is not None:
                    then(max(ev.t, now))
            return
        if k is K.DONE:
            if ev.gen == self.gen and self._awaiting is None and self.traj is not None:
                self.traj = None
                self._trajectory_done(ev.t)
            return
        if k is K.DIED:
            self.latch_fault(
                f"step executor died: {ev.detail}", now, lost=True, cause="executor_died"
            )
            return
        # the executor stopped the axis itself: answer (lifts its block), then decide
        if self._awaiting is not None and ev.gen < self._awaiting:
            return  # a stop of ours overtook it; that stop's answer settles the position
        if k is K.RELEASED:  # homing's back-off left the switch (it alone watches for that)
            if self.state is MotorState.HOMING and self._phase is HomingPhase.RELEASE:
                # zero where it released, once it stands (the answer; a chip that runs its
                # own ramp may still be braking)
                self._hard_stop(now, partial(self._homed, ev.mark))
            else:  # the back-off was being stopped (a soft StopMove): it stands now
                self._hard_stop(now, self._become_idle)
            return
        self.gen += 1
        self.executor.stop(self.index, self.gen)
        self.traj = None
        if k is K.ENDSTOP:
            cmd = self._home_cmd
            if (
                self.state is MotorState.HOMING
                and cmd is not None
                and self._phase in (HomingPhase.SEEK, HomingPhase.APPROACH)
                and ev.direction == cmd.direction
                and self.params.homing.source is HomingSource.ENDSTOP
            ):
                self._homing_triggered(max(ev.t, now))
            else:
                when = "while homing" if self.state is MotorState.HOMING else "outside homing"
                # on it before the first step toward it (no step made), or reached by one
                what = "already active" if ev.detail == ENDSTOP_ALREADY_ACTIVE else "hit"
                reason = f"end stop {what} at {self.position} {when}"
                self.latch_fault(reason, now, stopped=True, cause="endstop")
        elif k is K.TIMING_LOST:
            lost = ev.speed > self.params.start_speed
            self.latch_fault(
                f"step timing lost ({ev.detail})", now, lost=lost, stopped=True, cause="timing_lost"
            )
        else:  # a line failed: a step may or may not have reached the driver
            lost = ev.speed > self.params.start_speed
            self.latch_fault(
                ev.detail or "step executor fault", now, lost=lost, stopped=True, cause="io_error"
            )

    def on_driver_status(self, status: DriverStatus, now: float, steps: int | None = None) -> None:
        """A driver poll's result (read outside the engine lock, by the monitor); ``steps``:
        the step counter just before the read (default: now). A stall read before the motor
        stepped in its current motion is the last motion's (what a driver still says right
        after stall homing), not this one's."""
        if self.state is MotorState.FAULT:
            return
        if steps is None:
            steps = self.abs_steps
        if status.fault is not None:
            self.latch_fault(f"driver fault: {status.fault}", now, cause="driver")
        elif status.stall and self.active and self._awaiting is None and steps != self._started_at:
            if self._stall_homing:
                if self._phase in (HomingPhase.SEEK, HomingPhase.APPROACH):
                    self._hard_stop(now, self._homing_triggered)
            else:
                self.latch_fault("stall", now, cause="stall")

    # -- internals ----------------------------------------------------------
    @property
    def _stall_homing(self) -> bool:
        return self.state is MotorState.HOMING and self.params.homing.source is HomingSource.STALL

    def _hard_stop(self, now: float, then: Callable[[float], None]) -> None:
        """Stop at once; ``then`` runs once the executor has stopped (position final)."""
        self.traj = None
        self.gen += 1
        pos = self.executor.stop(self.index, self.gen)
        if pos is None:
            self._awaiting = self.gen
            self._then = then
        else:
            self._settled()
            then(now)

    def _settled(self) -> None:
        """No hard stop is awaited any more (the executor confirmed, or stopped on its own)."""
        if self._awaiting is not None:
            self._awaiting = None
            self.stops_settled += 1

    def _follow(
        self, traj: Trajectory, state: MotorState, now: float, *, release: bool = False
    ) -> None:
        was_active = self.active
        self.gen += 1
        self.traj = traj
        self.state = state
        watch = not self._stall_homing
        if not was_active:
            self._started_at = self.abs_steps
        moves = self.executor.follow(self.index, traj, self._ramp, self.gen, watch, release)
        if not was_active:
            self._notify(self, "start")
        if not moves:
            self.traj = None
            self._trajectory_done(max(now, traj.start_time))

    def _become_idle(self, now: float) -> None:
        self.traj = None
        self._phase = None
        self._home_cmd = None
        if self.fault is not None:  # fault_stop's ramp is done: at rest, the fault stays
            self.state = MotorState.FAULT
            self._notify(self, "stopped")
            return
        if self.queue:
            self._start(self.queue.popleft(), now)
            return
        self.state = MotorState.IDLE
        self._notify(self, "idle")

    def _start(self, cmd: MotionCmd, now: float) -> None:
        c = self.executor.committed(self.index, now)
        t, s, v = c.t, c.position, c.velocity
        self._ramp = cmd.ramp
        r = cmd.ramp
        if isinstance(cmd, MoveToCmd):
            target = c.counter + self._distance_to(cmd.target, cmd.direction, c)
            self._follow(
                plan_move_to(t, s, v, target, r.speed, r.acc, r.dec), MotorState.MOVING, now
            )
        elif isinstance(cmd, RunCmd):
            limit = self._soft_limit_abs(cmd.direction, c)
            r = self._ramp = self._dec_to_stop_in_limits(s, v, r, c)
            traj = plan_run(t, s, v, cmd.direction * r.speed, r.acc, r.dec, limit)
            self._follow(traj, MotorState.RUNNING, now)
        else:
            self._home_cmd = cmd
            if self._home_trigger(cmd.direction):
                self.state = MotorState.HOMING
                self._homing_triggered(now)
                return
            self._phase = HomingPhase.SEEK
            limit = c.counter + cmd.direction * self.params.homing.max_travel
            traj = plan_run(t, s, v, cmd.direction * r.speed, r.acc, r.dec, float(limit))
            self._follow(traj, MotorState.HOMING, now)

    def _host(self, counter: int) -> int:
        rel = counter - self.offset
        if self.params.rotary:
            return rel % self.params.steps_per_rev
        wrap = self.params.host_position
        return rel if wrap is None else wrap(rel)

    def _distance_to(self, target: int, direction: int, c: Committed) -> int:
        p = self.params
        cur = self._host(c.counter)
        if p.rotary:
            spr = p.steps_per_rev
            goal = target % spr
            return (goal - cur) % spr if direction > 0 else -((cur - goal) % spr)
        return target - cur

    def _soft_limit_abs(self, direction: int, c: Committed) -> float | None:
        p = self.params
        if p.rotary or p.soft_min is None or p.soft_max is None:
            return None
        limit = p.soft_max if direction > 0 else p.soft_min
        counter = c.counter
        return float(counter + (limit - self._host(counter)))

    def _dec_to_stop_in_limits(self, s: float, v: float, r: Ramp, c: Committed) -> Ramp:
        """``r`` with DEC raised just enough to stop short of the soft limit ahead of ``v``.

        A Move replanned with a lower DEC near a limit would otherwise overshoot it; the
        raised DEC is at most the one the running plan already stopped in time with.
        """
        ahead = self._soft_limit_abs(1 if v > 0 else -1, c) if v != 0 else None
        if ahead is None:
            return r
        room = abs(ahead - s) if (ahead - s) * v > 0 else 0.0
        if room <= 0 or v * v <= 2.0 * r.dec * room:
            return r
        return Ramp(r.speed, r.acc, v * v / (2.0 * room) * (1 + 1e-9))

    def _home_trigger(self, direction: int) -> bool:
        """Already on the switch (or stalled) when homing starts."""
        if self.params.homing.source is HomingSource.STALL:
            return self.driver.status().stall
        return self.params.debounce_s == 0 and self.executor.endstop_active(self.index, direction)

    def _homing_triggered(self, now: float) -> None:
        """The end stop triggered (or the motor stalled) toward it: back off, or zero."""
        cmd = self._home_cmd
        assert cmd is not None
        self.traj = None
        h = self.params.homing
        if h.pull_off > 0 and self._phase is not HomingPhase.APPROACH:
            self._phase = HomingPhase.BACKOFF
            c = self.executor.committed(self.index, now)
            counter = c.counter
            target = float(counter - cmd.direction * h.pull_off)
            r = cmd.ramp
            self._follow(
                plan_move_to(c.t, float(counter), 0.0, target, r.speed, r.acc, r.dec),
                MotorState.HOMING,
                now,
            )
            return
        if h.source is HomingSource.ENDSTOP:
            self._back_off_to_release(cmd, now)
            return
        self._homed(self.abs_steps, now)  # a stall: zero where it stalled

    def _back_off_to_release(self, cmd: HomeCmd, now: float) -> None:
        """Leave the switch at the slow speed until it releases (at most max_travel): the
        executor stops there and reports where it released (RELEASED), zero there."""
        self._phase = HomingPhase.RELEASE
        h = self.params.homing
        c = self.executor.committed(self.index, now)
        counter = c.counter
        limit = float(counter - cmd.direction * h.max_travel)
        r = cmd.ramp
        speed = min(h.second_speed, r.speed)
        traj = plan_run(c.t, float(counter), 0.0, -cmd.direction * speed, r.acc, r.dec, limit)
        self._follow(traj, MotorState.HOMING, now, release=True)

    def _homed(self, zero: int, now: float) -> None:
        """Position 0 at step counter ``zero``; homing is done."""
        self.offset = zero
        self.position_lost = False
        self._notify(self, "homed")
        self._become_idle(now)

    def _trajectory_done(self, now: float) -> None:
        """The executor made every step of the trajectory: the axis is at rest."""
        if self.state is MotorState.HOMING:
            cmd = self._home_cmd
            assert cmd is not None
            h = self.params.homing
            if self._phase is HomingPhase.BACKOFF:
                if self._still_on_switch(cmd.direction):
                    self.latch_fault(
                        "homing failed: end stop still active after pull-off",
                        now,
                        stopped=True,
                        cause="homing",
                    )
                    return
                self._phase = HomingPhase.APPROACH
                c = self.executor.committed(self.index, now)
                counter = c.counter
                limit = float(counter + cmd.direction * 2 * h.pull_off)
                r = cmd.ramp
                speed = min(h.second_speed, r.speed)
                traj = plan_run(
                    c.t, float(counter), 0.0, cmd.direction * speed, r.acc, r.dec, limit
                )
                self._follow(traj, MotorState.HOMING, now)
                return
            if self._phase is HomingPhase.RELEASE:
                self.latch_fault(
                    f"homing failed: end stop still active after backing off {h.max_travel} steps",
                    now,
                    stopped=True,
                    cause="homing",
                )
                return
            travel = h.max_travel if self._phase is HomingPhase.SEEK else 2 * h.pull_off
            self.latch_fault(
                f"homing failed: no end stop within {travel} steps",
                now,
                stopped=True,
                cause="homing",
            )
            return
        self._become_idle(now)

    def _still_on_switch(self, direction: int) -> bool:
        if self.params.homing.source is HomingSource.STALL:
            return False
        return self.executor.endstop_active(self.index, direction)
