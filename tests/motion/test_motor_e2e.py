"""Homing end to end (motion/motor.py), against motorctld as a process on a PTY over the mock
world, on each step core: a host's first program after InitMove -- home, move away, MoveTo 0,
WaitMoved, GetAbsPos 0 -- gets no E4, for each homing kind (the end stop, with and without the
second approach; the stall, on an axis without switches) and both directions. Zero is the
first position off the switch: one step further toward it is still an end stop hit (E4)."""

from __future__ import annotations

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.protocol.codec import ErrorCode
from tests.support.daemon_proc import StartDaemon

#: (name, [motors.homing] lines, homed by its switch) per kind; each homes both ways
KINDS = (
    ("endstop", "", True),
    ("pull_off", "pull_off = 40\nsecond_speed = 500.0", True),
    ("stall", 'source = "stall"', False),
)
#: the mock's end stops: the switch is active at and beyond them, the hard stop is there
ENDSTOP = 1500


def motors() -> list[tuple[str, int, bool]]:
    """(kind, direction, homed by its switch) of each motor, in config order."""
    return [(name, d, switch) for name, _, switch in KINDS for d in (1, -1)]


def config() -> str:
    homing = {name: lines for name, lines, _ in KINDS}
    out = []
    for name, d, switch in motors():
        out.append(f"""
[[motors]]
name = "{name}_{"up" if d > 0 else "down"}"
default_speed = 6000.0
default_accel = 60000.0
default_decel = 60000.0
  [motors.homing]
  speed = 6000.0
  max_travel = 5000
  {homing[name]}
  [motors.mock]
  endstop_min = -{ENDSTOP}
  endstop_max = {ENDSTOP}
  switches = {"true" if switch else "false"}
""")
    return "".join(out) + "\n[mock]\nwires = []\n"


@pytest.mark.parametrize("core", ["compiled", "python"])
def test_after_homing_moveto_0_and_back_gives_no_e4(motorctld: StartDaemon, core: str) -> None:
    daemon = motorctld(f'{config()}\n[step_thread]\ncore = "{core}"\n')
    assert daemon.status()["executor"]["core"] == core
    every = list(enumerate(motors()))
    with daemon.client() as c:
        for i, (_, d, _) in every:  # every motor at once, each step for all of them
            c.init_move(i, d > 0)
        wait_all(c, every)
        assert [c.position(i) for i, _ in every] == [0] * len(every)
        for i, (_, d, _) in every:
            c.move_to(i, -d * 800)  # away
        wait_all(c, every)
        for i, _ in every:
            c.move_to(i, 0)  # and back to where it homed
        wait_all(c, every)  # no E4: no switch touched, no stall
        assert [c.position(i) for i, _ in every] == [0] * len(every)
        assert all(c.is_ready(i) for i, _ in every)
        hits = [(i, d) for i, (_, d, switch) in every if switch]
        for i, d in hits:  # one step beyond 0 is on the switch: an end stop hit
            c.move_to(i, d)
        for i, d in hits:
            with pytest.raises(DeviceError) as hit:
                c.wait_moved(i, timeout_ms=10_000)
            assert hit.value.code is ErrorCode.MOTOR_ERROR, f"motor {i}"
            assert c.position(i) == d  # it stopped on the switch
            c.stop(i)  # clears it (the switch is no driver fault)
            c.move_to(i, 0)
            c.wait_moved(i, timeout_ms=10_000)
            assert c.position(i) == 0


def wait_all(c: Client, every: list[tuple[int, tuple[str, int, bool]]]) -> None:
    for i, (kind, d, _) in every:
        try:
            c.wait_moved(i, timeout_ms=10_000)
        except DeviceError as exc:
            raise AssertionError(f"motor {i} ({kind}, {'up' if d > 0 else 'down'}): {exc}") from exc
