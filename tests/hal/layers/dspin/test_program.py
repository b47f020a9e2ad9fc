"""What the protocol's motion commands become on the chip (program.py)."""

from __future__ import annotations

import pytest

from motorctl.hal.dspin.chips import L6470, L6480
from motorctl.hal.layers.dspin import program
from motorctl.hal.layers.dspin.convert import OutOfRange


def hexes(p: program.Program) -> list[str]:
    return [cmd.encode().hex(" ").upper() for cmd in p.commands]


def test_move_to_is_goto_dir_towards_the_target() -> None:
    # 1000 step/s at 1/16 = 62.5 full step/s -> MAX_SPEED 4; 1600 step/s^2 = 100 -> ACC 6
    p = program.move_to(L6470, 16, position=0, target=1000, speed=1000, acc=1600, dec=3200)
    assert hexes(p) == ["07 00 04", "05 00 06", "06 00 0D", "69 00 03 E8"]
    assert p.clamped == ()
    back = program.move_to(L6470, 16, position=1000, target=-3, speed=1000, acc=1600, dec=1600)
    assert hexes(back)[-1] == "68 3F FF FD"


def test_move_to_never_takes_the_short_way_round_on_a_linear_axis() -> None:
    # from -2,000,000 to +2,000,000: GoTo would go backwards through the 22-bit wrap
    # (the short way, 194,304 microsteps); GoTo_DIR forward goes the 4,000,000 asked
    p = program.move_to(
        L6480, 128, position=-2_000_000, target=2_000_000, speed=1e6, acc=1e6, dec=1e6
    )
    assert hexes(p)[-1] == "69 1E 84 80"
    with pytest.raises(OutOfRange, match="target 2097152"):
        program.move_to(L6480, 128, position=0, target=2**21, speed=1, acc=1, dec=1)


def test_move_to_on_a_rotary_axis_goes_to_the_wrapped_target_in_its_direction() -> None:
    # from 2,097,000 up 500 steps, past ABS_POS's end: GoTo_DIR forward to -2,096,804 (the
    # counter wraps on the way); down from there to before the end again
    up = program.move_to(L6470, 16, 2_097_000, 2_097_500, 1000, 1600, 1600, rotary=True)
    assert hexes(up)[-1] == "69 20 01 5C"  # 0x20015C: -2,096,804 in 22 bits
    down = program.move_to(L6470, 16, 2_097_500, 2_097_000, 1000, 1600, 1600, rotary=True)
    assert hexes(down)[-1] == "68 1F FF 68"  # 2,097,000
    # at most once round the counter less a step: a whole turn would not move at all
    program.move_to(L6470, 16, 0, 2**22 - 1, 1, 1, 1, rotary=True)
    with pytest.raises(OutOfRange, match="more than the dSPIN's GoTo_DIR goes"):
        program.move_to(L6470, 16, 0, -(2**22), 1, 1, 1, rotary=True)


def test_clamped_values_are_named() -> None:
    p = program.move_to(L6470, 128, position=0, target=10, speed=4, acc=16, dec=16)
    assert p.clamped == ("MAX_SPEED", "ACC", "DEC")


def test_move_writes_the_ramps_only_at_rest() -> None:
    at_rest = program.move(L6470, 1, True, speed=100, acc=160, dec=160, max_speed=900, at_rest=True)
    # MAX_SPEED floor(900 / 15.26) = 58; ACC/DEC 10; Run(FWD, floor(100 / 0.0149) = 6710)
    assert hexes(at_rest) == ["07 00 3A", "05 00 0A", "06 00 0A", "51 00 1A 36"]
    running = program.move(
        L6470, 1, False, speed=100, acc=160, dec=160, max_speed=900, at_rest=False
    )
    assert hexes(running) == ["07 00 3A", "50 00 1A 36"]


def test_home_is_gountil_then_releasesw_the_other_way() -> None:
    p = program.home(L6480, 1, False, speed=100, acc=160, dec=160)
    assert hexes(p) == ["07 00 06", "05 00 0A", "06 00 0A", "82 00 1A 36"]
    assert hexes(program.home(L6480, 1, True, 100, 160, 160, at_rest=False, act=1)) == [
        "07 00 06",
        "8B 00 1A 36",  # forward, ACT = copy ABS_POS to MARK; no ramps while moving
    ]
    # back off at 10 step/s: MIN_SPEED floor(10 / 0.2384) = 41 = 0x29; forward, ACT reset
    assert hexes(program.release(L6480, 1, False, 10)) == ["08 00 29", "93"]
    assert hexes(program.release(L6480, 1, True, 10, act=1)) == ["08 00 29", "9A"]


def test_move_to_while_running_keeps_the_ramps() -> None:
    p = program.move_to(L6470, 16, 0, 1000, speed=1000, acc=1600, dec=3200, at_rest=False)
    assert hexes(p) == ["07 00 04", "69 00 03 E8"]


def test_stop() -> None:
    assert hexes(program.stop(hard=True)) == ["B8"]
    assert hexes(program.stop(hard=False)) == ["B0"]
