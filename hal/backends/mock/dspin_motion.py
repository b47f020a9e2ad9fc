"""The motion engine of the mock dSPIN chip (dspin_chip.py), in the chip's own units: speed
in full steps per second, distance in microsteps, the ramps in full steps per second
squared, as the registers hold them (:mod:`motorctl.hal.dspin.scales`).

The speed profile of the datasheets (L6470 6.6 "Programmable speed profiles"): a motion
starts at MIN_SPEED (0 with LSPD_OPT), accelerates with ACC up to its target speed (MAX_SPEED
for Move, GoTo, GoTo_DIR, GoHome, GoMark; SPD capped to MIN_SPEED..MAX_SPEED for Run and
GoUntil), and a positioning command decelerates with DEC so as to arrive at its target;
SoftStop decelerates with DEC to a stop, HardStop stops at once. Run reverses through a
stop: down with DEC, then up again with ACC. ReleaseSW runs at MIN_SPEED (5 step/s at
least, and with LSPD_OPT) without a ramp.

Time advances in sub-steps of at most ``max_step`` seconds, each with a constant
acceleration; a positioning move is cut to arrive exactly on its target. Deterministic: the
same calls give the same motion. State owned by the chip that owns the engine (the thread
that drives the mock world).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from motorctl.hal.dspin.scales import RELEASE_SW_MIN_SPEED
from motorctl.hal.dspin.status import MotorState

MAX_STEP_S = 0.0005


class Kind(enum.Enum):
    IDLE = "idle"  # standing, holding (or in HiZ)
    RUN = "run"  # Run and GoUntil: towards a speed, for ever
    POSITION = "position"  # Move, GoTo, GoTo_DIR, GoHome, GoMark: towards a position
    RELEASE = "release"  # ReleaseSW: at the low speed, for ever
    STOP = "stop"  # SoftStop, SoftHiZ: down with DEC to a stop


@dataclass(frozen=True)
class Ramps:
    """What the registers say, in full steps: ACC, DEC, MAX_SPEED, MIN_SPEED (0 with
    LSPD_OPT), and the microsteps per full step of STEP_MODE."""

    acc: float
    dec: float
    max_speed: float
    min_speed: float
    microsteps: int
    lspd_opt: bool = False


class Motion:
    """One motor's motion: its speed (>= 0), direction (+1 forward, -1 reverse) and the
    command it carries out."""

    def __init__(self) -> None:
        self.speed = 0.0
        self.direction = 1
        self.kind = Kind.IDLE
        self.state = MotorState.STOPPED
        self.target_speed = 0.0  # RUN
        self.wanted_direction = 1  # RUN: reversing through a stop first
        self.remaining = 0  # POSITION: microsteps still to go in ``direction``
        self.reached = True  # RUN: the target speed was reached (BUSY is released)
        self.until = False  # RUN for GoUntil: BUSY until the motor stops
        self._carry = 0.0  # fractions of a microstep travelled

    @property
    def idle(self) -> bool:
        """No command under way (the motor stands, or is in HiZ)."""
        return self.kind is Kind.IDLE

    @property
    def stopped(self) -> bool:
        return self.kind is Kind.IDLE and self.speed == 0.0

    @property
    def busy(self) -> bool:
        """What BUSY says: a positioning, stopping or releasing motion, or a Run that has not
        reached its speed yet."""
        if self.kind is Kind.RUN:
            return self.until or not self.reached
        return self.kind is not Kind.IDLE

    # commands
    def run(self, direction: int, speed: float, ramps: Ramps, until: bool = False) -> None:
        """Run (``until``: GoUntil, BUSY until it stops): towards ``speed`` in
        ``direction`` (capped by the ramps)."""
        self.kind = Kind.RUN
        self.until = until
        self.wanted_direction = direction
        self.target_speed = min(max(speed, ramps.min_speed), ramps.max_speed)
        self.reached = False
        self._start(direction, ramps)

    def position(self, direction: int, distance: int, ramps: Ramps) -> None:
        """Move ``distance`` microsteps in ``direction`` (the chip checked it stands still
        or, for GoTo, that BUSY is released)."""
        if distance <= 0:
            self.halt()
            return
        if self.speed > 0 and direction != self.direction:
            self.halt()  # the chip only starts a move from rest or in its direction
        self.kind = Kind.POSITION
        self.remaining = distance
        self._start(direction, ramps)

    def release(self, direction: int, ramps: Ramps) -> None:
        """ReleaseSW: at MIN_SPEED, but 5 step/s if that is less or LSPD_OPT is set."""
        low = ramps.min_speed
        if ramps.lspd_opt or low < float(RELEASE_SW_MIN_SPEED):
            low = float(RELEASE_SW_MIN_SPEED)
        self.kind = Kind.RELEASE
        self.direction = direction
        self.speed = low
        self.state = MotorState.CONSTANT_SPEED

    def soft_stop(self) -> None:
        if self.speed == 0.0:
            self.halt()
        else:
            self.kind = Kind.STOP

    def halt(self) -> None:
        """HardStop: no speed at once."""
        self.kind = Kind.IDLE
        self.speed = 0.0
        self.state = MotorState.STOPPED
        self.remaining = 0
        self.reached = True
        self.until = False

    def _start(self, direction: int, ramps: Ramps) -> None:
        if self.speed == 0.0:
            self.direction = direction
            self.speed = 0.0 if ramps.lspd_opt else ramps.min_speed

    # time
    def advance(self, dt: float, ramps: Ramps) -> int:
        """Move on by ``dt`` seconds; the microsteps travelled (signed)."""
        moved = 0
        steps = max(1, math.ceil(dt / MAX_STEP_S - 1e-9))
        for _ in range(steps):
            moved += self._advance(dt / steps, ramps)
            if self.kind is Kind.IDLE:
                break
        return moved

    def _advance(self, dt: float, ramps: Ramps) -> int:
        if self.kind is Kind.IDLE:
            return 0
        v0 = self.speed
        accel = self._acceleration(ramps)
        v1 = v0 + accel * dt
        v1 = self._bound(v1, accel, ramps)
        full = (v0 + v1) / 2 * dt  # full steps, constant acceleration
        self.speed = v1
        micro = full * ramps.microsteps + self._carry
        whole = math.floor(micro)
        self._carry = micro - whole
        if self.kind is Kind.POSITION and whole >= self.remaining:
            whole = self.remaining
            self.halt()
            self._carry = 0.0
            return whole * self.direction
        if self.kind is Kind.POSITION:
            self.remaining -= whole
        self._after(ramps)
        return whole * self.direction

    def _acceleration(self, ramps: Ramps) -> float:
        """The acceleration (full step/s^2) of this instant, and MOT_STATUS with it."""
        v = self.speed
        if self.kind is Kind.STOP or (
            self.kind is Kind.RUN and self.wanted_direction != self.direction
        ):
            self.state = MotorState.DECELERATION
            return -ramps.dec
        if self.kind is Kind.RELEASE:
            return 0.0
        if self.kind is Kind.POSITION:
            low = 0.0 if ramps.lspd_opt else ramps.min_speed
            braking = (v * v - low * low) / (2 * ramps.dec) if ramps.dec > 0 else math.inf
            if self.remaining / ramps.microsteps <= braking + v * MAX_STEP_S:
                self.state = MotorState.DECELERATION
                return -ramps.dec if v > low else 0.0
            target = ramps.max_speed
        else:
            target = self.target_speed
        if v < target:
            self.state = MotorState.ACCELERATION
            return ramps.acc
        if v > target:
            self.state = MotorState.DECELERATION
            return -ramps.dec
        self.state = MotorState.CONSTANT_SPEED
        return 0.0

    def _bound(self, v1: float, accel: float, ramps: Ramps) -> float:
        """The speed after a sub-step, not past the speed the ramp heads for."""
        low = 0.0 if ramps.lspd_opt else ramps.min_speed
        if self.kind is Kind.POSITION:
            return min(max(v1, low if accel < 0 else 0.0), ramps.max_speed)
        if self.kind is Kind.RUN and self.wanted_direction == self.direction:
            if accel > 0:
                return min(v1, self.target_speed)
            if accel < 0:
                return max(v1, self.target_speed)
        return max(v1, 0.0)

    def _after(self, ramps: Ramps) -> None:
        """What ends with the sub-step: a stop reached, a reversal's stop, a speed reached."""
        low = 0.0 if ramps.lspd_opt else ramps.min_speed
        decelerating = self.kind is Kind.STOP or (
            self.kind is Kind.RUN and self.wanted_direction != self.direction
        )
        if decelerating and self.speed <= low:
            if self.kind is Kind.STOP:
                self.halt()
                return
            self.direction = self.wanted_direction  # reversed through the stop
            self.speed = low
            return
        if self.kind is Kind.RUN and math.isclose(self.speed, self.target_speed):
            self.speed = self.target_speed
            self.reached = True
            self.state = MotorState.CONSTANT_SPEED
