"""A rotary axis on a dSPIN chip (issue 34): the chip's ABS_POS wraps at 22 bits as the axis
turns (2,097,151 + 1 = -2,097,152, as the mock chip model counts it, and the datasheets'
two's complement counter does), and the driver counts on past the wrap, so the axis behaves
as on a STEP/DIR motor: a Move runs on, GetAbsPos reports 0..steps_per_rev-1, a MoveTo goes
in DIR to the angle across the wrap. A linear axis keeps ABS_POS's range: a target beyond it
is refused (E1), a Move stops at its end.

The dispatcher and the motion engine of a config over the mock world's chain, on a virtual
clock; the chip starts a few thousand microsteps short of ABS_POS's end, as a chip whose
motor has turned for a while (its register set as SetParam(ABS_POS) would)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.config.model import MotorConfig
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.start.assemble import build_executor, hardware_spec, motor_params
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.dspin.config import DspinConfig
from motorctl.hal.layers.dspin.convert import ABS_POS_MAX, ABS_POS_MIN
from motorctl.hal.registry import open_hardware
from motorctl.motion.engine import MotionEngine
from motorctl.protocol.codec import (
    Command,
    ErrorCode,
    GetAbsPos,
    IsReady,
    Move,
    MoveTo,
    Response,
    StopMove,
)
from motorctl.schema.spec import Key

#: steps per revolution of the rotary axis (a 200-step motor at 1/16, geared 1:4): not a
#: divisor of ABS_POS's span, so the wrap is not a whole number of turns
SPR = 12800
ABS_POS_SPAN = ABS_POS_MAX - ABS_POS_MIN + 1  # 2^22: ABS_POS wraps by it
SPEED = 8000.0
REPO = Path(__file__).resolve().parents[4]  # step/s: a Move's default speed


def config(steps_per_rev: int) -> str:
    return f"""\
[[motors]]
name = "table"
steps_per_rev = {steps_per_rev}
default_speed = {SPEED}
default_accel = 80000.0
default_decel = 80000.0
  [motors.mock]
  endstop_min = -1000000
  endstop_max = 1000000
  switches = false
  [motors.dspin]
  driver = "l6470"
  spi = "/dev/spidev0.0"
  microsteps = 16
  switch = "none"
"""


@dataclass
class Rig:
    clock: VirtualClock
    chip: DspinChip
    engine: MotionEngine
    dispatcher: Dispatcher

    def send(self, cmd: Command) -> Response:
        return self.dispatcher.handle(cmd)

    def position(self) -> int:
        return self.send(GetAbsPos(0)).as_position

    def run(self, seconds: float) -> None:
        self.engine.run_until(self.clock.now() + seconds)

    def until_ready(self, limit_s: float = 5.0) -> None:
        end = self.clock.now() + limit_s
        while not self.send(IsReady(0)).as_bool:
            assert self.clock.now() < end, "the motor did not stop"
            self.run(0.01)


def rig(steps_per_rev: int, abs_pos: int) -> Rig:
    """The machine of :func:`config`, its chip's ABS_POS at ``abs_pos`` before the daemon
    reads it."""
    clock = VirtualClock()
    cfg = parse_config(config(steps_per_rev), "t.toml")
    spec = hardware_spec(cfg)
    params = motor_params(cfg)
    hw = open_hardware(cfg.hal.backend, spec, clock)
    nodes = world_of(hw).spi_nodes
    assert nodes is not None
    chip = nodes.chains[(0, 0)].members[0].chip
    chip.regs["ABS_POS"] = abs_pos
    engine = MotionEngine(hw, params, build_executor(cfg, hw, spec, params))
    return Rig(clock, chip, engine, Dispatcher(cfg, engine, hw.pins))


def test_a_rotary_axis_runs_on_past_abs_pos_s_wrap_and_goes_to_an_angle_in_dir() -> None:
    start = ABS_POS_MAX - 3000
    r = rig(SPR, start)
    angle = r.position()
    assert angle == start % SPR
    assert r.send(Move(0, True, 0, 0, 0)).ack
    r.run(1.0)  # ~7,500 microsteps at 8,000 step/s: past the wrap
    assert not r.send(IsReady(0)).as_bool  # it runs on
    assert r.chip.abs_pos < 0  # the chip's counter wrapped
    turned = r.chip.abs_pos + ABS_POS_SPAN - start
    assert turned > 3000
    assert r.position() == (angle + turned) % SPR  # the angle, counted across the wrap
    assert r.send(StopMove(0, False)).ack
    r.until_ready()
    at = r.chip.abs_pos + ABS_POS_SPAN  # where it stands, counted on past the wrap
    assert r.position() == (angle + at - start) % SPR and r.chip.motion.stopped
    # back across the wrap in DIR (down) to the angle 1,000 steps short of the start: the
    # other way round (up) would be shorter
    back = at - (start + 1000)
    assert SPR / 2 < back < SPR
    target = (angle + 1000) % SPR
    assert r.send(MoveTo(0, False, target, 0, 0, 0)).ack
    r.until_ready()
    assert r.position() == target and r.chip.abs_pos == start + 1000
    # and up across it again, 5,000 steps on
    assert r.send(MoveTo(0, True, (target + 5000) % SPR, 0, 0, 0)).ack
    r.until_ready()
    assert r.position() == (target + 5000) % SPR
    assert r.chip.abs_pos == start + 6000 - ABS_POS_SPAN
    assert not r.chip.latched & {"NOTPERF_CMD", "WRONG_CMD"}


def test_get_abs_pos_counts_on_over_many_wraps() -> None:
    # the counter as a motor turning 1,500,000 microsteps between two of the executor's
    # reads leaves it (less than half its span), ten times: seven wraps, each one counted
    r = rig(SPR, 0)
    for n in range(1, 11):
        r.chip.regs["ABS_POS"] = (n * 1_500_000 - ABS_POS_MIN) % ABS_POS_SPAN + ABS_POS_MIN
        r.run(0.1)  # a read at rest comes every ramp_idle_poll_ms
        assert r.position() == n * 1_500_000 % SPR


def test_a_linear_axis_refuses_targets_beyond_abs_pos_and_its_move_stops_at_the_end() -> None:
    r = rig(0, ABS_POS_MAX - 3000)
    refused = r.send(MoveTo(0, True, ABS_POS_MAX + 1, 0, 0, 0))
    assert refused.error_code is ErrorCode.INVALID_COMMAND
    assert r.send(Move(0, True, 0, 0, 0)).ack
    r.until_ready()  # at the end of ABS_POS's range, as at a soft limit
    assert r.position() == ABS_POS_MAX == r.chip.abs_pos


def test_reads_a_period_apart_cannot_miss_a_wrap_within_the_config_s_bounds() -> None:
    # the driver takes each ABS_POS read as the position nearest the one before: a motor
    # at the fastest max_speed the config takes, read at its slowest ramp_poll_ms, moves a
    # tenth of half the counter's span between two reads
    def hi(cls: type, name: str) -> float:
        field = {f.name: f for f in dataclasses.fields(cls)}[name]
        key = field.metadata["motorctl.schema.key"]
        assert isinstance(key, Key) and isinstance(key.hi, int | float)
        return float(key.hi)

    speed, period = hi(MotorConfig, "max_speed"), hi(DspinConfig, "ramp_poll_ms")
    per_period = speed * period / 1000
    assert per_period * 10 <= ABS_POS_SPAN // 2
    said = " ".join((REPO / "docs" / "dspin.md").read_text(encoding="utf-8").split())
    assert f"`[dspin] ramp_poll_ms` (at most {period:g})" in said
    assert f"`max_speed` (at most {speed:,.0f} step/s), so at most {per_period:,.0f}" in said


def test_a_rotary_axis_s_revolution_is_within_one_go_to_dir() -> None:
    with pytest.raises(Exception, match="steps_per_rev"):
        parse_config(config(ABS_POS_SPAN + 1), "t.toml")
    parse_config(config(ABS_POS_SPAN), "t.toml")
