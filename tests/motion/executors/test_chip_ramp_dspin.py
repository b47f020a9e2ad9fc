"""The chip-ramp executor (motion/executors/chip_ramp.py) moving dSPIN chips: the dSPIN
layer's drivers (hal/layers/dspin/driver.py) on the mock world's register-level chain, on a
virtual clock. MoveTo is GoTo_DIR, a run is Run (GoUntil towards the switch), a stop while
the chip ramps is SoftStop, homing's back-off is ReleaseSW with the position MARK took."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal import registry
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.backends.mock.world import MockAxis, world_of
from motorctl.hal.interfaces import Hardware, VirtualClock
from motorctl.hal.layers.dspin.convert import ABS_POS_MAX, ABS_POS_MIN
from motorctl.hal.layers.dspin.driver import DspinDriver
from motorctl.motion.executors.base import ENDSTOP_ALREADY_ACTIVE, ExecEvent, ExecEventKind
from motorctl.motion.executors.chip_ramp import RampExecutor
from motorctl.motion.profile import plan_move_to, plan_run
from motorctl.motion.types import Ramp

K = ExecEventKind
RAMP = Ramp(4000.0, 40_000.0, 40_000.0)
CONFIG = """\
[[motors]]
name = "x"
  [motors.mock]
  endstop_min = -1500
  [motors.dspin]
  driver = "l6480"
  spi = "/dev/spidev0.0"
  microsteps = 16
"""


class SlowBus(VirtualClock):
    """A virtual clock that moves on by ``tick`` seconds at every reading: each SPI transfer
    finds the chips later than the one before (the separate reads of a poll, as on a loaded
    machine)."""

    def __init__(self, tick: float) -> None:
        super().__init__()
        self.tick = tick

    def now(self) -> float:
        self.advance(self.tick)
        return super().now()


class DspinRig:
    def __init__(self, clock: VirtualClock | None = None) -> None:
        self.clock = clock or VirtualClock()
        self.hw: Hardware = registry.open_hardware(
            "mock", hardware_spec(parse_config(CONFIG, "t.toml")), self.clock
        )
        driver = self.hw.steppers[0].driver
        assert isinstance(driver, DspinDriver)
        self.driver = driver
        nodes = world_of(self.hw).spi_nodes
        assert nodes is not None
        self.chain = nodes.chains[(0, 0)]
        self.chip: DspinChip = self.chain.members[0].chip
        self.axis: MockAxis = self.chain.members[0].axis
        self.ex = RampExecutor([driver], self.clock, poll_s=0.002, idle_poll_s=0.02)
        self.ex.start()
        self.seen: list[ExecEvent] = []

    def run(self, until: Callable[[], bool], limit_s: float) -> None:
        t0 = self.clock.now()
        while True:
            self.seen += self.ex.events()
            if until():
                return
            assert self.clock.now() - t0 < limit_s, f"not done within {limit_s} s: {self.seen}"
            nxt = self.ex.service(self.clock.now())
            self.clock.advance_to(max(nxt, self.clock.now() + 1e-4))

    def kinds(self) -> list[ExecEventKind]:
        return [e.kind for e in self.seen]

    def sent(self) -> list[int]:
        return [out[0] for out, _ in self.chain.chain.transfers]


@pytest.fixture
def rig() -> DspinRig:
    return DspinRig()


def test_a_move_to_is_go_to_dir_and_ends_exactly_there(rig: DspinRig) -> None:
    start = len(rig.chain.chain.transfers)
    traj = plan_move_to(rig.clock.now(), 0.0, 0.0, 6000.0, RAMP.speed, RAMP.acc, RAMP.dec)
    assert rig.ex.follow(0, traj, RAMP, gen=1)
    assert 0x69 in rig.sent()[start:]  # GoTo_DIR forward
    rig.run(lambda: K.DONE in rig.kinds(), 5.0)
    assert rig.seen[-1].position == 6000 == rig.chip.abs_pos == rig.axis.position


def test_an_end_stop_hit_is_reported_where_the_chip_stands_though_its_reads_are_apart() -> None:
    # the poll's reads of ABS_POS, SPEED and STATUS are separate transfers: STATUS first,
    # so a motor it finds standing is reported where it stood, not where it was a read ago
    rig = DspinRig(SlowBus(0.0005))
    traj = plan_move_to(rig.clock.now(), 0.0, 0.0, -5000.0, 4000.0, 1e5, 1e5)
    rig.ex.follow(0, traj, Ramp(4000.0, 1e5, 1e5), gen=1)
    rig.run(lambda: K.ENDSTOP in rig.kinds(), 5.0)
    assert rig.seen[-1].position == -1500 == rig.chip.abs_pos


@pytest.mark.parametrize("direction", [1, -1])
def test_a_run_stops_exactly_at_the_end_of_abs_pos_and_is_done_there(
    rig: DspinRig, direction: int
) -> None:
    # past ABS_POS's end the chip's counter would wrap: the run stays a Run (which the
    # chip takes at any time, so a Move may still reverse it) until braking must start,
    # then it is a GoTo_DIR to the end, where it is done as at a soft limit; towards the
    # switch it is a GoUntil, which keeps BUSY low and takes no GoTo: a SoftStop just short
    end = ABS_POS_MAX if direction > 0 else ABS_POS_MIN
    rig.chip.regs["ABS_POS"] = end - direction * 3000
    rig.axis.endstop_min = -(10**7)  # no switch on the way
    rig.ex.start()
    start = len(rig.chain.chain.transfers)
    run = plan_run(rig.clock.now(), 0.0, 0.0, direction * 4000.0, 40_000.0, 40_000.0, None)
    rig.ex.follow(0, run, RAMP, gen=1)
    assert {0x51 if direction > 0 else 0x50, 0x8A} & set(rig.sent()[start:])  # Run, GoUntil
    rig.run(lambda: K.DONE in rig.kinds(), 5.0)
    done = rig.seen[-1]
    assert done.gen == 1 and done.position == rig.chip.abs_pos == rig.ex.position(0)
    assert rig.chip.motion.stopped
    if direction > 0:
        assert done.position == end
    else:  # two polls' travel (driver poll_s 5 ms) at most, and never past the end
        assert end <= done.position <= end + 4000 * 2 * 0.005 + 1
    assert not rig.chip.latched & {"NOTPERF_CMD", "WRONG_CMD"}


def test_a_stop_while_the_chip_ramps_is_a_soft_stop_and_settles_where_it_stands(
    rig: DspinRig,
) -> None:
    run = plan_run(rig.clock.now(), 0.0, 0.0, 3000.0, 10_000.0, 10_000.0, None)
    rig.ex.follow(0, run, Ramp(3000.0, 10_000.0, 10_000.0), gen=1)
    rig.run(lambda: rig.ex.position(0) > 100, 2.0)
    assert rig.chip.busy  # still accelerating: a GoTo would be NOTPERF_CMD
    here = rig.ex.position(0)
    stop = plan_move_to(rig.clock.now(), float(here), 3000.0, here + 450.0, 3000, 1e4, 1e4)
    rig.ex.follow(0, stop, RAMP, gen=2)
    assert rig.sent()[-1] == 0xB0  # SoftStop
    rig.run(lambda: K.DONE in rig.kinds(), 5.0)  # settled: DONE where it stands
    assert rig.seen[-1].gen == 2 and rig.seen[-1].position == rig.chip.abs_pos
    assert not rig.chip.latched & {"NOTPERF_CMD", "WRONG_CMD"}


def test_a_motion_toward_the_switch_closed_already_is_not_sent_to_the_chip(
    rig: DspinRig,
) -> None:
    """SW stops the chip as it closes (SW_EVN, SW_MODE 0), not while it is closed: a GoTo_DIR
    or Run toward a switch closed already would run on into the machine's end. The executor
    sees it closed in the read each motion starts from (``committed()``) and reports ENDSTOP
    at once, nothing sent to the chip; a move away goes to the chip as ever."""
    speed, acc, dec = RAMP.speed, RAMP.acc, RAMP.dec
    rig.ex.follow(0, plan_move_to(rig.clock.now(), 0.0, 0.0, -5000.0, speed, acc, dec), RAMP, 1)
    rig.run(lambda: K.ENDSTOP in rig.kinds(), 5.0)
    hit = rig.seen[-1]
    assert (
        (hit.position, hit.detail) == (-1500, "reference switch") == (rig.chip.abs_pos, hit.detail)
    )
    for gen in (2, 4, 6):  # StopMove, then a MoveTo or Move down again: the chip is not moved
        rig.ex.stop(0, gen)
        rig.run(lambda: rig.seen[-1].kind is K.STOPPED, 1.0)
        here = float(rig.ex.committed(0, rig.clock.now()).counter)
        start = len(rig.sent())
        if gen == 4:
            down = plan_run(rig.clock.now(), here, 0.0, -2000.0, acc, dec, None)
        else:
            down = plan_move_to(rig.clock.now(), here, 0.0, -5000.0, speed, acc, dec)
        assert rig.ex.follow(0, down, RAMP, gen + 1)
        rig.run(lambda: rig.seen[-1].kind is K.ENDSTOP, 1.0)
        ev = rig.seen[-1]
        assert (ev.gen, ev.position, ev.direction) == (gen + 1, -1500, -1)
        assert ev.detail == ENDSTOP_ALREADY_ACTIVE and rig.sent()[start:] == []
    rig.ex.stop(0, 8)
    rig.run(lambda: rig.seen[-1].kind is K.STOPPED, 1.0)
    assert rig.chip.abs_pos == -1500 == rig.axis.position
    here = float(rig.ex.committed(0, rig.clock.now()).counter)
    assert rig.ex.follow(
        0, plan_move_to(rig.clock.now(), here, 0.0, -500.0, speed, acc, dec), RAMP, 9
    )
    rig.run(lambda: rig.seen[-1].kind is K.DONE, 5.0)
    assert rig.ex.position(0) == -500 == rig.axis.position


def test_a_run_to_the_switch_is_go_until_and_the_back_off_release_sw_both_mark_it(
    rig: DspinRig,
) -> None:
    seek = plan_run(rig.clock.now(), 0.0, 0.0, -2000.0, 40_000.0, 40_000.0, None)
    rig.ex.follow(0, seek, RAMP, gen=1)
    assert rig.sent()[-4] == 0x8A  # GoUntil(ACT = copy to MARK, DIR reverse), SPD's 3 bytes
    rig.run(lambda: K.ENDSTOP in rig.kinds(), 5.0)
    hit = rig.seen[-1]
    assert hit.direction == -1 and hit.position == -1500  # MARK: the switch's edge
    assert rig.ex.stop(0, gen=2) is None
    rig.run(lambda: K.STOPPED in rig.kinds(), 1.0)
    here = rig.ex.position(0)
    back = plan_run(rig.clock.now(), float(here), 0.0, 200.0, 4e4, 4e4, here + 5000.0)
    rig.ex.follow(0, back, RAMP, gen=3, endstops=False, release=True)
    assert rig.sent()[-1] == 0x9B  # ReleaseSW(ACT = copy to MARK, DIR forward)
    rig.run(lambda: K.RELEASED in rig.kinds(), 5.0)
    released = rig.seen[-1]
    assert released.mark == rig.chip.regs["MARK"] and -1500 <= released.mark <= -1498


def test_a_release_sw_whose_switch_never_opens_stops_at_its_limit(rig: DspinRig) -> None:
    rig.axis.force("min", True)
    rig.chip.set_switch(True)
    back = plan_run(rig.clock.now(), 0.0, 0.0, 200.0, 4e4, 4e4, 300.0)
    rig.ex.follow(0, back, RAMP, gen=1, endstops=False, release=True)
    rig.run(lambda: K.DONE in rig.kinds(), 10.0)
    assert 300 <= rig.seen[-1].position < 330  # ReleaseSW at MIN_SPEED, hard-stopped there
    assert rig.chip.busy is False
