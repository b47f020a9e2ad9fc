"""Motion commands and per-motor parameters, in steps, step/s and step/s^2."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Ramp:
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
    """Seek the end stop in ``direction``; position 0 there."""

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
    """Where a homing run is: towards the end stop, backing off it, or re-approaching it."""

    SEEK = "seek"
    BACKOFF = "backoff"
    APPROACH = "approach"


@dataclass(frozen=True)
class HomingParams:
    source: HomingSource = HomingSource.ENDSTOP
    max_travel: int = 40_000
    pull_off: int = 0  # 0 = one-phase homing
    second_speed: float = 250.0


@dataclass(frozen=True)
class MotorParams:
    name: str = "motor"
    steps_per_rev: int = 0  # 0 = linear axis
    queue_depth: int = 16
    max_waypoints: int = 255
    soft_min: int | None = None
    soft_max: int | None = None
    homing: HomingParams = HomingParams()
    debounce_s: float = 0.0
    dir_setup_s: float = 5e-6
    pulse_s: float = 2e-6
    max_speed: float = 25_000.0  # step/s: no plan is faster (the executor's spacing bound)
    start_speed: float = 100.0  # step/s: a motor stopped from above may have lost steps
    microsteps: int = 16  # per full step: a late step's lag is judged in full steps
    max_lag_full_steps: float = 0.5  # a lag beyond this, above start_speed, loses steps
    # How a linear axis shows its step count to the host: the daemon passes the protocol's
    # counter (motorctl.protocol.codec.wrap24: 24-bit two's complement). None: unbounded.
    # Motion does not know the protocol, so the wrap is passed in, not defined here.
    host_position: Callable[[int], int] | None = None

    @property
    def rotary(self) -> bool:
        return self.steps_per_rev > 0
