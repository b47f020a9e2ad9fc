"""One stepper motor: state machine, motion queue, homing, limits, faults.

Positions: ``abs_steps`` is an unbounded count of the steps emitted since start;
the host's position is ``abs_steps - offset`` mapped by ``params.host_position`` (linear
axis; the daemon passes the protocol's 24-bit wrap) or taken modulo ``steps_per_rev``
(rotary axis). Trajectories are planned in
``abs_steps`` coordinates, so wrapping never reaches the profile math.

All methods are called with the engine's lock held.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from motorctl.hal.interfaces import InputLine, StepperHardware
from motorctl.motion.latency import LatencyStats
from motorctl.motion.profile import Steps, Trajectory, plan_move_to, plan_run, plan_stop
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


class Debounce:
    """An input that must read active for ``debounce_s`` before it counts."""

    def __init__(self, line: InputLine | None, active_low: bool, debounce_s: float) -> None:
        self.line = line
        self.active_low = active_low
        self.debounce_s = debounce_s
        self._since: float | None = None

    def active(self) -> bool:
        return self.line is not None and self.line.read() != self.active_low

    def triggered(self, now: float) -> bool:
        if not self.active():
            self._since = None
            return False
        if self._since is None:
            self._since = now
        return now - self._since >= self.debounce_s

    def reset(self) -> None:
        self._since = None


class Motor:
    def __init__(
        self,
        index: int,
        params: MotorParams,
        hw: StepperHardware,
        stats: LatencyStats,
        notify: Callable[[Motor, str], None],
        endstop_active_low: bool = False,
    ) -> None:
        self.index = index
        self.params = params
        self.hw = hw
        self.stats = stats
        self._notify = notify
        self.state = MotorState.IDLE
        self.queue: deque[MotionCmd] = deque()
        self.abs_steps = 0
        self.offset = 0
        self.home = 0
        self.waypoints: list[int] = []
        self.fault: str | None = None
        self.position_lost = False
        self.traj: Trajectory | None = None
        self._steps: Steps | None = None
        self.next_step: tuple[float, int] | None = None
        self._ramp = Ramp(1.0, 1.0, 1.0)
        self._phase: HomingPhase | None = None  # while homing
        self._home_cmd: HomeCmd | None = None
        self._endstops = {
            1: Debounce(hw.endstop_max, endstop_active_low, params.debounce_s),
            -1: Debounce(hw.endstop_min, endstop_active_low, params.debounce_s),
        }

    # -- what the host sees -------------------------------------------------
    @property
    def position(self) -> int:
        rel = self.abs_steps - self.offset
        if self.params.rotary:
            return rel % self.params.steps_per_rev
        wrap = self.params.host_position
        return rel if wrap is None else wrap(rel)

    def set_position(self, position: int) -> None:
        """Declare the current physical position to be ``position`` (homing, restore)."""
        self.offset = self.abs_steps - position

    @property
    def idle(self) -> bool:
        return self.state is MotorState.IDLE and not self.queue

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
        if self.state is MotorState.IDLE and not self.queue:
            return False
        return len(self.queue) >= self.params.queue_depth

    def target_allowed(self, target: int) -> bool:
        p = self.params
        if p.soft_min is None or p.soft_max is None or p.rotary:
            return True
        return p.soft_min <= target <= p.soft_max

    # -- commands -----------------------------------------------------------
    def submit(self, cmd: MotionCmd, now: float) -> None:
        """Queue a motion command (the caller checked faults and queue space)."""
        if self.state is MotorState.IDLE and not self.queue:
            self._start(cmd, now)
        elif (
            isinstance(cmd, RunCmd)
            and self.state is MotorState.RUNNING
            and not self.queue
        ):
            self._start(cmd, now)  # a Move while running: change at once along the ramps
        else:
            self.queue.append(cmd)

    def stop(self, hard: bool, now: float) -> bool:
        """StopMove: empty the queue, stop; clear a latched fault if the driver allows.

        Returns False when a latched fault remains (the driver still reports one).
        """
        self.queue.clear()
        if self.state is MotorState.FAULT:
            status = self.hw.driver.status()
            if status.fault is not None:
                return False
            self.fault = None
            self.state = MotorState.IDLE
            self._notify(self, "cleared")
            return True
        if not self.active:
            return True
        if hard or self.traj is None:
            self._halt()
            self._become_idle(now)
        else:
            s, v = self._kinematics(now)
            self._install(plan_stop(now, s, v, self._ramp.dec), MotorState.STOPPING)
            if self.next_step is None:
                self._become_idle(now)
        return True

    def latch_fault(self, reason: str, now: float) -> None:
        """Stop at once and latch a fault: every command but StopMove/GetAbsPos gets E4."""
        self._halt()
        self.queue.clear()
        self.fault = reason
        self.state = MotorState.FAULT
        self._phase = None
        self._notify(self, "fault")

    # -- the step thread's side ----------------------------------------------
    def fire(self, now: float) -> None:
        """Emit the due step, then check end stops and what comes next."""
        step = self.next_step
        assert step is not None and self._steps is not None
        t, d = step
        port = self.hw.port
        port.set_direction(d > 0)
        ready = port.direction_set_at + self.params.dir_setup_s
        if now < ready:
            port.clock.spin_until(ready)
        edge = port.pulse(self.params.pulse_s)
        self.stats.record(edge - t)
        self.abs_steps += d
        nxt = self._steps.next()
        self.next_step = nxt
        if nxt is not None and nxt[1] != d:
            port.set_direction(nxt[1] > 0)  # early, well before the reversal's first step
        if self._check_after_step(edge, d):
            return
        if self.next_step is None:
            self._trajectory_done(edge)

    def poll_driver(self, now: float) -> None:
        if self.state is MotorState.FAULT:
            return
        status = self.hw.driver.status()
        if status.fault is not None:
            self.latch_fault(f"driver fault: {status.fault}", now)
        elif status.stall and self.active and not self._stall_homing:
            self.latch_fault("stall", now)

    # -- internals ----------------------------------------------------------
    @property
    def _stall_homing(self) -> bool:
        return self.state is MotorState.HOMING and self.params.homing.source is HomingSource.STALL

    def _kinematics(self, now: float) -> tuple[float, float]:
        """Continuous position and velocity now, consistent with the step counter."""
        if self.traj is None:
            return float(self.abs_steps), 0.0
        s = self.traj.position(now)
        lo, hi = self.abs_steps - 0.999, self.abs_steps + 0.999
        return min(max(s, lo), hi), self.traj.velocity(now)

    def _install(self, traj: Trajectory, state: MotorState) -> None:
        was_active = self.active
        self.traj = traj
        self._steps = Steps(traj, self.abs_steps)
        self.next_step = self._steps.next()
        self.state = state
        if self.next_step is not None:
            self.hw.port.set_direction(self.next_step[1] > 0)
        if not was_active:
            self._notify(self, "start")

    def _halt(self) -> None:
        self.traj = None
        self._steps = None
        self.next_step = None
        for endstop in self._endstops.values():
            endstop.reset()  # unwatched from now on: a later motion debounces afresh

    def _become_idle(self, now: float) -> None:
        self._halt()
        self._phase = None
        self._home_cmd = None
        if self.queue:
            self._start(self.queue.popleft(), now)
            return
        self.state = MotorState.IDLE
        self._notify(self, "idle")

    def _start(self, cmd: MotionCmd, now: float) -> None:
        s, v = self._kinematics(now)
        self._ramp = cmd.ramp
        r = cmd.ramp
        if isinstance(cmd, MoveToCmd):
            target = self.abs_steps + self._distance_to(cmd.target, cmd.direction)
            self._install(plan_move_to(now, s, v, target, r.speed, r.acc, r.dec), MotorState.MOVING)
        elif isinstance(cmd, RunCmd):
            limit = self._soft_limit_abs(cmd.direction)
            r = self._ramp = self._dec_to_stop_in_limits(s, v, r)
            traj = plan_run(now, s, v, cmd.direction * r.speed, r.acc, r.dec, limit)
            self._install(traj, MotorState.RUNNING)
        else:
            self._home_cmd = cmd
            self._endstops[cmd.direction].reset()
            if self._home_trigger(cmd.direction, now):
                self._homing_triggered(now)
                return
            self._phase = HomingPhase.SEEK
            limit = self.abs_steps + cmd.direction * self.params.homing.max_travel
            traj = plan_run(now, s, v, cmd.direction * r.speed, r.acc, r.dec, float(limit))
            self._install(traj, MotorState.HOMING)
        if self.next_step is None:
            self._trajectory_done(now)

    def _distance_to(self, target: int, direction: int) -> int:
        p = self.params
        if p.rotary:
            spr = p.steps_per_rev
            cur = self.position
            goal = target % spr
            return (goal - cur) % spr if direction > 0 else -((cur - goal) % spr)
        return target - self.position

    def _soft_limit_abs(self, direction: int) -> float | None:
        p = self.params
        if p.rotary or p.soft_min is None or p.soft_max is None:
            return None
        limit = p.soft_max if direction > 0 else p.soft_min
        return float(self.abs_steps + (limit - self.position))

    def _dec_to_stop_in_limits(self, s: float, v: float, r: Ramp) -> Ramp:
        """``r`` with DEC raised just enough to stop short of the soft limit ahead of ``v``.

        A Move replanned with a lower DEC near a limit would otherwise overshoot it; the
        raised DEC is at most the one the running plan already stopped in time with.
        """
        ahead = self._soft_limit_abs(1 if v > 0 else -1) if v != 0 else None
        if ahead is None:
            return r
        room = abs(ahead - s) if (ahead - s) * v > 0 else 0.0
        if room <= 0 or v * v <= 2.0 * r.dec * room:
            return r
        return Ramp(r.speed, r.acc, v * v / (2.0 * room) * (1 + 1e-9))

    def _home_trigger(self, direction: int, now: float) -> bool:
        if self.params.homing.source is HomingSource.STALL:
            return self.hw.driver.status().stall
        return self._endstops[direction].triggered(now)

    def _check_after_step(self, now: float, d: int) -> bool:
        """End-stop logic after a step; True when it ended the current trajectory."""
        self._endstops[-d].reset()  # only the end stop ahead is watched
        if self.state is MotorState.HOMING:
            cmd = self._home_cmd
            assert cmd is not None
            seeking = self._phase in (HomingPhase.SEEK, HomingPhase.APPROACH)
            if seeking and self._home_trigger(cmd.direction, now):
                self._homing_triggered(now)
                return True
            return False
        if self._endstops[d].triggered(now):
            self.latch_fault("end stop hit", now)
            return True
        return False

    def _homing_triggered(self, now: float) -> None:
        cmd = self._home_cmd
        assert cmd is not None
        self._halt()
        h = self.params.homing
        if h.pull_off > 0 and self._phase is not HomingPhase.APPROACH:
            self._phase = HomingPhase.BACKOFF
            target = float(self.abs_steps - cmd.direction * h.pull_off)
            r = cmd.ramp
            traj = plan_move_to(now, float(self.abs_steps), 0.0, target, r.speed, r.acc, r.dec)
            self._install(traj, MotorState.HOMING)
            return
        self.set_position(0)
        self.position_lost = False
        self._notify(self, "homed")
        self._become_idle(now)

    def _trajectory_done(self, now: float) -> None:
        if self.state is MotorState.HOMING:
            cmd = self._home_cmd
            assert cmd is not None
            h = self.params.homing
            if self._phase is HomingPhase.BACKOFF:
                self._endstops[cmd.direction].reset()
                if self._endstops[cmd.direction].active():
                    self.latch_fault("homing failed: end stop still active after pull-off", now)
                    return
                self._phase = HomingPhase.APPROACH
                limit = float(self.abs_steps + cmd.direction * 2 * h.pull_off)
                r = cmd.ramp
                speed = min(h.second_speed, r.speed)
                traj = plan_run(now, float(self.abs_steps), 0.0, cmd.direction * speed,
                                r.acc, r.dec, limit)
                self._install(traj, MotorState.HOMING)
                if self.next_step is None:
                    self._trajectory_done(now)
                return
            travel = h.max_travel if self._phase is HomingPhase.SEEK else 2 * h.pull_off
            self.latch_fault(f"homing failed: no end stop within {travel} steps", now)
            return
        self._become_idle(now)
