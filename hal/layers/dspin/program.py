"""What each of the protocol's motion commands becomes on a dSPIN: the chip commands, in
order, with the registers they need (docs/dspin.md, "The protocol's commands on the chip").

- MoveTo (and GoHome, MoveToWayPoint with the saved position): MAX_SPEED, ACC and DEC
  when the motor stands, then GoTo_DIR towards the target, never GoTo: GoTo takes the
  shortest way round ABS_POS's 22 bits, which for a distance of 2^21 or more is the wrong
  way on a linear axis. On a rotary axis the positions go on past ABS_POS's 22 bits: the
  target is wrapped to them and reached in the direction of travel.
- Move: MAX_SPEED (the motor's maximum: Run runs at min(SPD, MAX_SPEED)), ACC and DEC when
  the motor stands (they are writable only then: a Move that changes a running Move keeps
  the ramps it has), then Run.
- To the switch (:func:`home`): ACC and DEC when the motor stands, MAX_SPEED (GoUntil runs
  at min(SPD, MAX_SPEED)), then GoUntil in DIR; once the switch has stopped it
  (:func:`release`), MIN_SPEED (the speed ReleaseSW backs off at, never below 5 full
  step/s) and ReleaseSW the other way: zero where the switch releases. The layer's driver
  gives both ACT = copy ABS_POS to MARK (the position stays continuous; the motor's zero is
  set at MARK) and uses :func:`home` for a run without limit towards the switch; InitMove's
  run to the switch, limited by ``homing.max_travel``, reaches it as a :func:`move_to` that
  the switch stops (CONFIG's SW_MODE 0), and backs off with :func:`release`.
- StopMove: SoftStop (IS_HARDSTOP FALSE) or HardStop.

Each returns the commands and the names of the values that had to be clamped
(:mod:`~motorctl.hal.layers.dspin.convert`). Pure: any thread.
"""

from __future__ import annotations

from dataclasses import dataclass

from motorctl.hal.dspin.chips import Chip
from motorctl.hal.dspin.commands import (
    FORWARD,
    RESET_ABS_POS,
    REVERSE,
    Command,
    Op,
    go_to_dir,
    go_until,
    release_sw,
    run,
    set_param,
    simple,
)
from motorctl.hal.layers.dspin import convert
from motorctl.hal.layers.dspin.convert import Setting


@dataclass(frozen=True)
class Program:
    """Chip commands in order, and which of the asked values were clamped."""

    commands: tuple[Command, ...]
    clamped: tuple[str, ...] = ()


def _settings(chip: Chip, settings: dict[str, Setting]) -> Program:
    cmds = tuple(set_param(chip.registers[name], s.register) for name, s in settings.items())
    return Program(cmds, tuple(name for name, s in settings.items() if s.clamped))


def move_to(
    chip: Chip,
    microsteps: int,
    position: int,
    target: int,
    speed: float,
    acc: float,
    dec: float,
    at_rest: bool = True,
    rotary: bool = False,
) -> Program:
    """MoveTo ``target`` from ``position`` at ``speed`` step/s with ramps ``acc``, ``dec``
    step/s^2, the ramps written only ``at_rest`` (a GoTo given while the chip runs at its
    speed keeps the ramps it has); :class:`~convert.OutOfRange` for a target ABS_POS cannot
    hold (E1). ``rotary``: the positions go past ABS_POS's range (the chip's counter wraps
    as the axis turns): GoTo_DIR to the target wrapped to 22 bits, in the direction of
    travel; :class:`~convert.OutOfRange` for a move of a whole turn of the counter or more."""
    if rotary:
        register = convert.check_turn(position, target)
    else:
        register = convert.check_position(target, "target")
    wanted = {"MAX_SPEED": convert.max_speed(speed, microsteps)}
    if at_rest:
        wanted["ACC"] = convert.ramp(acc, microsteps)
        wanted["DEC"] = convert.ramp(dec, microsteps)
    setup = _settings(chip, wanted)
    direction = FORWARD if target >= position else REVERSE
    return Program((*setup.commands, go_to_dir(direction, register)), setup.clamped)


def move(
    chip: Chip,
    microsteps: int,
    up: bool,
    speed: float,
    acc: float,
    dec: float,
    max_speed: float,
    at_rest: bool,
) -> Program:
    """Move (run until stopped) ``up`` or down at ``speed`` step/s; ``max_speed``: the
    motor's maximum (MAX_SPEED caps Run); the ramps are written only ``at_rest``."""
    wanted = {"MAX_SPEED": convert.max_speed(max(max_speed, speed), microsteps)}
    if at_rest:
        wanted["ACC"] = convert.ramp(acc, microsteps)
        wanted["DEC"] = convert.ramp(dec, microsteps)
    setup = _settings(chip, wanted)
    spd = convert.run_speed(speed, microsteps)
    clamped = (*setup.clamped, "SPD") if spd.clamped else setup.clamped
    return Program((*setup.commands, run(FORWARD if up else REVERSE, spd.register)), clamped)


def home(
    chip: Chip,
    microsteps: int,
    up: bool,
    speed: float,
    acc: float,
    dec: float,
    at_rest: bool = True,
    act: int = RESET_ABS_POS,
) -> Program:
    """InitMove's first phase: to the switch ``up`` or down at ``speed`` step/s (MAX_SPEED
    caps GoUntil), ``act`` where it closes (ABS_POS reset, or copied to MARK); the ramps
    written only ``at_rest``."""
    wanted = {"MAX_SPEED": convert.max_speed(speed, microsteps)}
    if at_rest:
        wanted["ACC"] = convert.ramp(acc, microsteps)
        wanted["DEC"] = convert.ramp(dec, microsteps)
    setup = _settings(chip, wanted)
    spd = convert.run_speed(speed, microsteps)
    clamped = (*setup.clamped, "SPD") if spd.clamped else setup.clamped
    direction = FORWARD if up else REVERSE
    return Program((*setup.commands, go_until(act, direction, spd.register)), clamped)


def release(
    chip: Chip, microsteps: int, up: bool, speed: float, act: int = RESET_ABS_POS
) -> Program:
    """InitMove's second phase, after :func:`home` towards ``up`` (the motor stands): back
    off the other way at ``speed`` step/s (MIN_SPEED; the chip never goes below 5 full
    step/s there) until the switch opens, ``act`` there, hard stop."""
    setup = _settings(chip, {"MIN_SPEED": convert.min_speed(speed, microsteps)})
    return Program((*setup.commands, release_sw(act, REVERSE if up else FORWARD)), setup.clamped)


def stop(hard: bool) -> Program:
    """StopMove: HardStop (IS_HARDSTOP TRUE) or SoftStop along DEC."""
    return Program((simple(Op.HARD_STOP if hard else Op.SOFT_STOP),))
