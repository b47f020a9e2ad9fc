"""Motion commands and per-motor parameters, in steps, step/s and step/s^2."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Ramp:
    """A move's speed limit and its acceleration and deceleration."""

    speed: float  # step/s
    acc: float  # step/s^2
    dec: float  # step/s^2


@dataclass(frozen=True)
class MoveToCmd:
    """Go to ``target`` (a position as the host counts it). ``direction`` matters on rotary axes."""

    target: int
    ramp: Ramp
    direction: int = 1


@dataclass(frozen=True)
class RunCmd:
    """Run continuously in ``direction`` (+1/-1) until stopped (or a soft limit)."""

    direction: int
    ramp: Ramp


@dataclass(frozen=True)
class HomeCmd:
    """Seek the end stop in ``direction``; position 0 where it releases again when backed off
    (a stall: where it stalled)."""

    direction: int
    ramp: Ramp


MotionCmd = MoveToCmd | RunCmd | HomeCmd


class MotorState(enum.Enum):
    IDLE = "idle"
    MOVING = "moving"
    RUNNING = "running"
    HOMING = "homing"
    STOPPING = "stopping"
    FAULT = "fault"


class HomingSource(enum.StrEnum):
    """What ends a homing run."""

    ENDSTOP = "endstop"  # the end-stop input
    STALL = "stall"  # the driver's stall flag (sensorless homing)


class HomingPhase(enum.Enum):
    """Where a homing run is: towards the end stop, backing off it (pull_off), re-approaching
    it, or backing off slowly until it releases (position 0 there)."""

    SEEK = "seek"
    BACKOFF = "backoff"
    APPROACH = "approach"
    RELEASE = "release"


@dataclass(frozen=True)
class HomingParams:
    """How a motor homes: what it seeks (end stop or stall), how far at most, how far it
    backs off again."""

    source: HomingSource = HomingSource.ENDSTOP
    max_travel: int = 40_000
    pull_off: int = 0  # 0 = one-phase homing
    # step/s of the slow phases: the re-approach (pull_off > 0) and the back-off to release
    second_speed: float = 250.0


@dataclass(frozen=True)
class MotorParams:
    """One motor as motion sees it: its geometry, soft limits, queue, homing, timing, speed
    limits and how its position is counted (on the host, on a driver chip)."""

    name: str = "motor"
    # The motor's config: the config model declares the defaults ([[motors]]), so these
    # are always given (the daemon: daemon/start/assemble.py's motor_params)
    steps_per_rev: int = field(kw_only=True)  # 0 = linear axis
    queue_depth: int = field(kw_only=True)
    # the table size: the config model declares its default (the protocol's table), so
    # always given
    max_waypoints: int = field(kw_only=True)
    soft_min: int | None = None
    soft_max: int | None = None
    homing: HomingParams = HomingParams()
    debounce_s: float = 0.0
    dir_setup_s: float = 5e-6
    pulse_s: float = 2e-6
    # step/s: no plan is faster (the executor's spacing bound); always given
    max_speed: float = field(kw_only=True)
    # step/s: a motor stopped from above may have lost steps; its default is the config
    # model's ([[motors]] start_speed), so always given
    start_speed: float = field(kw_only=True)
    # per full step: a late step's lag is judged in full steps; always given
    microsteps: int = field(kw_only=True)
    # a lag beyond this, above start_speed, loses steps (always given: [[motors]])
    max_lag_full_steps: float = field(kw_only=True)
    # How a linear axis shows its step count to the host: the daemon passes the protocol's
    # counter (motorctl.protocol.codec.wrap24: 24-bit two's complement). None: unbounded.
    # Motion does not know the protocol, so the wrap is passed in, not defined here.
    host_position: Callable[[int], int] | None = None
    # The driver's own position counter's range where the chip moves the motor itself (a
    # dSPIN's ABS_POS); a target beyond it is refused. None: the steps are counted here.
    counter_range: tuple[int, int] | None = None

    @property
    def rotary(self) -> bool:
        return self.steps_per_rev > 0
