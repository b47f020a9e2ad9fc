"""What each protocol command costs on a dSPIN chain: the SPI transfers the daemon of
docs/examples/dspin.toml (a chain of three: an L6470, an L6480, a powerSTEP01, on the mock
backend, a virtual clock) makes while it handles one command, read back out of the mock
chain's transcript as each chip parses its byte stream (byte ``2 - chip`` of each
transfer, docs/dspin.md "On the wire"). One STATUS/ABS_POS read per command where the
chip's answer is needed, none where it is not; the counts follow from the datasheets'
framing: a command byte and its argument or answer bytes, one transfer each (GetStatus
1 + 2, GetParam ABS_POS and SPEED 1 + 3, SetParam MAX_SPEED, ACC and DEC 1 + 2, GoTo_DIR
and Run 1 + 3, SoftStop and HardStop 1)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from motorctl.hal.backends.mock.dspin_chain import DspinChain
from motorctl.hal.backends.mock.dspin_chip import DspinChip
from motorctl.hal.backends.mock.world import world_of
from motorctl.hal.dspin.chips import Chip
from motorctl.hal.dspin.commands import FORWARD, Command, Op, decode
from motorctl.hal.layers.dspin.driver import DspinDriver
from motorctl.protocol.codec import Command as HostCommand
from motorctl.protocol.codec import ErrorCode, GetAbsPos, IsReady, Move, MoveTo, StopMove
from tests.support import REPO
from tests.support.sessions import SessionRig

EXAMPLE = (REPO / "docs" / "examples" / "dspin.toml").read_text()


def documented(command: str) -> int:
    """The transfers docs/dspin.md's table ("One read per motion command") gives
    ``command``."""
    lines = (REPO / "docs" / "dspin.md").read_text(encoding="utf-8").splitlines()
    start = lines.index("| command | transfers | on chip 0 |")
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[0] == command:
            return int(cells[1])
    raise AssertionError(f"docs/dspin.md's table has no row {command!r}")


@dataclass(frozen=True)
class Sent:
    """One command as one chip read it: the command, and its transfers."""

    command: Command
    transfers: int

    @property
    def name(self) -> str:
        reg = self.command.register
        return self.command.op.value + (f"({reg.name})" if reg is not None else "")


def per_chip(chips: list[Chip], transfers: list[tuple[bytes, bytes]], chip: int) -> list[Sent]:
    """Chip ``chip``'s commands out of ``transfers`` (sent, received), parsed as the chip
    parses its bytes; NOPs left out."""
    slot = len(chips) - 1 - chip
    out = []
    i = 0
    while i < len(transfers):
        d = decode(chips[chip], transfers[i][0][slot])
        assert not d.wrong, f"transfer {i}: chip {chip} gets a byte it has no command for"
        n = d.follows
        tail = transfers[i + 1 : i + 1 + n]
        reads = d.op in (Op.GET_PARAM, Op.GET_STATUS)
        arg = bytes(t[0][slot] for t in tail)
        if reads:
            assert arg == bytes(n), f"transfer {i}: NOPs must clock chip {chip}'s answer out"
        if d.op is not Op.NOP:
            out.append(Sent(d.command(b"" if reads else arg), 1 + n))
        i += 1 + n
    return out


class Chain:
    """The example's daemon and its chain: what one host command costs on the wire."""

    def __init__(self, tmp: Path) -> None:
        self.rig = SessionRig(tmp, EXAMPLE)
        self.rig.run(0.2)
        nodes = world_of(self.rig.daemon.hw).spi_nodes
        assert nodes is not None
        chain = nodes.chains[(0, 0)]
        self.bus: DspinChain = chain.chain
        self.chips: list[DspinChip] = [m.chip for m in chain.members]
        drivers = [s.driver for s in self.rig.daemon.hw.steppers]
        assert all(isinstance(d, DspinDriver) for d in drivers)
        self.models = [d.chip for d in drivers if isinstance(d, DspinDriver)]

    def cost(self, cmd: HostCommand) -> tuple[int, list[Sent]]:
        """Send ``cmd``: its answer must be no error; the transfers it cost and what chip 0
        (motor 0's) got in them (the other chips get NOPs only)."""
        start = self.bus.count
        kept = len(self.bus.transfers)
        assert self.rig.call(cmd).error_code is None, cmd
        n = self.bus.count - start
        assert len(self.bus.transfers) == kept + n  # the whole of it is in the transcript
        transfers = list(self.bus.transfers)[kept:]
        assert per_chip(self.models, transfers, 1) == per_chip(self.models, transfers, 2) == []
        return n, per_chip(self.models, transfers, 0)


@pytest.fixture
def chain(tmp_path: Path) -> Chain:
    return Chain(tmp_path)


def names(sent: list[Sent]) -> list[str]:
    return [s.name for s in sent]


def test_a_move_to_from_rest_reads_status_and_abs_pos_once(chain: Chain) -> None:
    n, sent = chain.cost(MoveTo(0, True, 1000, 250, 50, 50))
    assert names(sent) == [
        "GetStatus",  # STATUS, the old motion's latched switch event cleared (SW_EVN)
        "GetParam(ABS_POS)",  # where the motor stands: GoTo_DIR's direction, the plan's start
        "SetParam(MAX_SPEED)",
        "SetParam(ACC)",  # the ramps: writable only while the motor stands
        "SetParam(DEC)",
        "GoTo_DIR",
    ]
    assert sent[-1].command == Command(Op.GO_TO_DIR, dir=FORWARD, value=1000)
    assert [s.transfers for s in sent] == [3, 4, 3, 3, 3, 4]
    assert n == 20 == documented("MoveTo from rest")
    chain.rig.run(10.0)
    assert chain.rig.call(GetAbsPos(0)).as_position == 1000 == chain.chips[0].abs_pos


def test_is_ready_and_get_abs_pos_cost_no_transfer_at_rest_or_moving(chain: Chain) -> None:
    assert documented("GetAbsPos, IsReady") == 0
    assert chain.cost(IsReady(0)) == (0, [])
    assert chain.cost(GetAbsPos(0)) == (0, [])
    chain.cost(MoveTo(0, True, 1000, 250, 50, 50))
    chain.rig.run(0.05)
    assert chain.chips[0].busy  # moving: the executor's poll is what they answer from
    assert chain.cost(IsReady(0)) == (0, [])
    assert chain.cost(GetAbsPos(0)) == (0, [])


def test_a_move_from_rest_reads_status_and_abs_pos_once(chain: Chain) -> None:
    n, sent = chain.cost(Move(0, True, 1, 50, 50))
    assert names(sent) == [
        "GetStatus",
        "GetParam(ABS_POS)",
        "SetParam(MAX_SPEED)",
        "SetParam(ACC)",
        "SetParam(DEC)",
        "Run",
    ]
    assert n == 20 == documented("Move from rest")


def test_a_move_reversing_a_running_move_reads_once(chain: Chain) -> None:
    chain.cost(Move(0, True, 1, 50, 50))
    chain.rig.run(0.3)
    n, sent = chain.cost(Move(0, False, 1, 50, 50))
    # moving: SPEED (the plan's start), DEC (the Run keeps the ramps it has: the end of
    # ABS_POS's range is watched with it); down is towards x's switch: GoUntil
    assert names(sent) == [
        "GetStatus",
        "GetParam(ABS_POS)",
        "GetParam(SPEED)",
        "GetParam(DEC)",
        "SetParam(MAX_SPEED)",
        "GoUntil",
    ]
    assert n == 21 == documented("Move reversing a running Move")


def test_a_soft_stop_while_the_chip_ramps_is_one_read_and_a_soft_stop(chain: Chain) -> None:
    chain.cost(Move(0, True, 1, 50, 50))
    chain.rig.run(0.05)
    assert chain.chips[0].busy  # accelerating: it takes no GoTo
    n, sent = chain.cost(StopMove(0, False))
    assert names(sent) == ["GetStatus", "GetParam(ABS_POS)", "GetParam(SPEED)", "SoftStop"]
    assert n == 12 == documented("StopMove, the chip still ramping")
    assert not chain.chips[0].latched & {"NOTPERF_CMD", "WRONG_CMD"}


def test_a_soft_stop_at_speed_is_a_go_to_dir_from_where_the_motor_is_now(chain: Chain) -> None:
    chain.cost(Move(0, True, 1, 255, 50))  # 4096 step/s, reached within 1 s
    chain.rig.run(1.5)
    assert not chain.chips[0].busy and not chain.chips[0].motion.stopped  # at its speed
    n, sent = chain.cost(StopMove(0, False))
    # GoTo_DIR to where DEC stops it: the moving motor's ABS_POS read again just before,
    # so that the direction is towards the target from where the motor is, not was
    assert names(sent) == [
        "GetStatus",
        "GetParam(ABS_POS)",
        "GetParam(SPEED)",
        "GetParam(ABS_POS)",
        "SetParam(MAX_SPEED)",
        "GoTo_DIR",
    ]
    assert n == 22 == documented("StopMove, at constant speed")
    chain.rig.run(5.0)
    assert chain.rig.call(IsReady(0)).as_bool
    assert not chain.chips[0].latched & {"NOTPERF_CMD", "WRONG_CMD"}


def test_a_hard_stop_is_a_hard_stop_then_the_read_of_where_it_stopped(chain: Chain) -> None:
    chain.cost(Move(0, True, 1, 50, 50))
    chain.rig.run(0.3)
    n, sent = chain.cost(StopMove(0, True))
    assert names(sent) == [
        "HardStop",
        "GetParam(STATUS)",  # the executor's poll, due at once: the stop's position
        "GetParam(ABS_POS)",  # (standing: no SPEED read, it is 0)
    ]
    assert n == 8 == documented("StopMove hard")
    chain.rig.run(0.2)
    assert chain.rig.call(GetAbsPos(0)).as_position == chain.chips[0].abs_pos


def test_a_fault_the_commands_get_status_clears_still_reaches_the_host(chain: Chain) -> None:
    # the GetStatus before a MoveTo clears the chip's latched OCD: the driver keeps it for
    # the poller's next reading, so the host hears E4 all the same
    chain.chips[0].inject("OCD")
    chain.chips[0].inject("OCD", False)  # gone, but latched until a GetStatus
    _, sent = chain.cost(MoveTo(0, True, 1000, 250, 50, 50))
    assert names(sent)[0] == "GetStatus"
    assert "OCD" not in chain.chips[0].latched  # cleared by it
    chain.rig.run(0.02)  # [drivers] poll_ms = 5: the poll has come
    assert chain.rig.call(IsReady(0)).error_code is ErrorCode.MOTOR_ERROR
