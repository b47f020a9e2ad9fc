"""The protocol's units to the dSPIN registers, and the rule for what the chip cannot take.

The daemon hands a motor's speeds in step/s (the protocol's SPEED x 4096 for InitMove and
Move, SPEED x 4 for MoveTo and MoveToWayPoint), its ramps in step/s^2 (ACC, DEC x 16) and
positions in steps. A dSPIN counts positions in microsteps of its step mode (ABS_POS, MARK,
Move's N_STEP), so a protocol step is one microstep; but its speed and ramp registers count
FULL steps per tick (:mod:`motorctl.hal.dspin.scales`). Each conversion here divides by the
motor's microsteps per full step and then picks the register value.

The rule (docs/dspin.md, "Values the chip cannot take"), written once here:

- **Speeds and ramps are clamped, never refused** (the protocol clamps speeds above a
  motor's maximum and never refuses them). A value is rounded DOWN to the register's
  resolution: the chip never runs faster or ramps harder than asked. A value above the
  register's range becomes its largest value; a positive value below its smallest step
  becomes that smallest step (MAX_SPEED 15.26, ACC/DEC 14.55 full step/s^2 and the Run
  speed 0.015 full step/s: the only case where the chip goes faster than asked). Either
  clamp is reported (``clamped``) for the daemon's ``clamped`` count. MIN_SPEED and FS_SPD
  round down too; MIN_SPEED may be 0.
- **Positions outside ABS_POS's 22 bits are refused** (E1): -2,097,152..2,097,151
  microsteps, a quarter of the protocol's 24-bit range; config refuses soft limits, home
  and waypoints beyond it (:func:`check_position`). A rotary axis has no such range: its
  positions go on past ABS_POS's 22 bits, which the chip wraps as it turns
  (:func:`abs_pos`, :func:`unwrap`); a GoTo_DIR goes less than one turn of the counter
  (:func:`check_turn`).

Pure: any thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from typing import Final

from motorctl.hal.dspin import scales
from motorctl.hal.dspin.counter import ABS_POS_BITS
from motorctl.hal.dspin.counter import ABS_POS_MAX as ABS_POS_MAX
from motorctl.hal.dspin.counter import ABS_POS_MIN as ABS_POS_MIN
from motorctl.hal.dspin.counter import ABS_POS_SPAN as ABS_POS_SPAN  # wraps by it
from motorctl.hal.dspin.scales import Scale

N_STEP_MAX: Final = (1 << ABS_POS_BITS) - 1


class OutOfRange(ValueError):
    """A value the chip cannot take and the protocol refuses (E1); the message says what
    and why."""


@dataclass(frozen=True)
class Setting:
    """A register value for an asked value: ``value`` is what the chip will do, in the
    protocol's units; ``clamped``: the asked value was outside the register's range."""

    register: int
    value: float
    clamped: bool


def _setting(scale: Scale, asked: float, microsteps: int, keep_moving: bool) -> Setting:
    if microsteps < 1:
        raise ValueError(f"microsteps must be >= 1, not {microsteps}")
    if asked < 0:
        raise ValueError(f"{scale.name}: {asked} is negative (directions are separate)")
    full = Fraction(asked) / microsteps
    reg = scale.floor(full)
    lo = max(scale.lo, 1) if keep_moving and asked > 0 else scale.lo
    clamped = reg < lo or reg > scale.hi
    reg = min(max(reg, lo), scale.hi)
    return Setting(reg, float(scale.value(reg) * microsteps), clamped)


def run_speed(step_s: float, microsteps: int) -> Setting:
    """Run's and GoUntil's SPD (and the SPEED register's scale) for ``step_s``."""
    return _setting(scales.SPEED, step_s, microsteps, keep_moving=True)


def max_speed(step_s: float, microsteps: int) -> Setting:
    """MAX_SPEED, the cruise speed of Move, GoTo, GoTo_DIR, GoHome, GoMark."""
    return _setting(scales.MAX_SPEED, step_s, microsteps, keep_moving=True)


def min_speed(step_s: float, microsteps: int) -> Setting:
    """MIN_SPEED (its low 12 bits; LSPD_OPT is bit 12): where a ramp starts and ends, and
    ReleaseSW's speed (never below 5 full step/s)."""
    return _setting(scales.MIN_SPEED, step_s, microsteps, keep_moving=False)


def fs_speed(step_s: float, microsteps: int) -> Setting:
    """FS_SPD (its low 10 bits): the speed above which the chip drives full steps."""
    return _setting(scales.FS_SPD, step_s, microsteps, keep_moving=False)


def ramp(step_s2: float, microsteps: int) -> Setting:
    """ACC or DEC for ``step_s2`` (the same scale)."""
    return _setting(scales.ACC, step_s2, microsteps, keep_moving=True)


def speed_of(register: int, microsteps: int) -> float:
    """The SPEED register's value (a GetParam(SPEED)) in the protocol's step/s."""
    return float(scales.SPEED.value(register) * microsteps)


def position_fits(position: int) -> bool:
    """Whether ``position`` (steps = microsteps) is a value ABS_POS can hold."""
    return ABS_POS_MIN <= position <= ABS_POS_MAX


def check_position(position: int, what: str = "position") -> int:
    """``position`` if ABS_POS can hold it, else :class:`OutOfRange` (E1) saying so."""
    if not position_fits(position):
        raise OutOfRange(
            f"{what} {position} is outside the dSPIN's ABS_POS range {ABS_POS_MIN}.."
            f"{ABS_POS_MAX} (22 bits of microsteps)"
        )
    return position


def check_distance(steps: int) -> int:
    """Move's N_STEP for a distance of ``steps`` (>= 0): at most 2^22 - 1, else
    :class:`OutOfRange`."""
    if not 0 <= steps <= N_STEP_MAX:
        raise OutOfRange(f"a move of {steps} steps is outside Move's N_STEP 0..{N_STEP_MAX}")
    return steps


def abs_pos(position: int) -> int:
    """``position`` (a rotary axis's, past ABS_POS's range) as ABS_POS holds it: wrapped
    to 22 bits of two's complement, as the chip's counter wraps when it turns on."""
    return (position - ABS_POS_MIN) % ABS_POS_SPAN + ABS_POS_MIN


def unwrap(value: int, near: int) -> int:
    """The position an ABS_POS read of ``value`` stands for: of those the counter shows as
    ``value``, the one nearest ``near`` (the position the read before found). Unambiguous
    while the motor moved less than half of ABS_POS's span (2,097,152 microsteps) between
    the two reads."""
    return near + abs_pos(value - near)


def check_turn(position: int, target: int) -> int:
    """``target`` as GoTo_DIR's ABS_POS for a motion from ``position`` (a rotary axis's
    positions), if the chip can go that far in one GoTo_DIR: less than a whole turn of its
    counter (at most 2^22 - 1 microsteps), else :class:`OutOfRange`."""
    if abs(target - position) > N_STEP_MAX:
        raise OutOfRange(
            f"a move of {abs(target - position)} steps is more than the dSPIN's GoTo_DIR "
            f"goes ({N_STEP_MAX}: once round ABS_POS's 22 bits)"
        )
    return abs_pos(target)
