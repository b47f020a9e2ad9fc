"""motorctld serving end to end (daemon/start/serve.py and everything it runs): a subprocess on a
real PTY, driven through the client library: every command and error code, framing, held
frames, persistence across restarts, stop signals, both step executors and the executor's
death."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.daemon.start.serve import EXECUTOR_DEATH_GRACE_S, SHUTDOWN_LIMIT_S
from motorctl.protocol.codec import (
    CodecOptions,
    Command,
    ErrorCode,
    GetAbsPos,
    IsReady,
    MoveTo,
    Response,
    SetPin,
    StopMove,
    WaitMoved,
    encode_command,
)
from motorctl.protocol.crc import SMBUS
from tests.support.daemon_proc import (
    DaemonProcess,
    StartDaemon,
    children_of,
    memfd_holders,
    memfd_labels,
)
from tests.support.frames import frame, raw_frame
from tests.support.wait import until

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

E = ErrorCode
OPTS = CodecOptions()

SMALL = """
[[motors]]
name = "a"
queue_depth = 2
max_waypoints = 2
soft_limit_min = -500
soft_limit_max = 500
  [motors.homing]
  max_travel = 300

[[motors]]
name = "r"
steps_per_rev = 400
default_speed = 4000

[[pins]]
number = 0
mode = "output"

[[pins]]
number = 1
mode = "input"
"""


@pytest.fixture
def daemon(motorctld: StartDaemon) -> DaemonProcess:
    return motorctld()


@pytest.fixture
def client(daemon: DaemonProcess) -> Iterator[Client]:
    with daemon.client() as c:
        yield c


@pytest.fixture
def small(motorctld: StartDaemon) -> DaemonProcess:
    return motorctld(SMALL)


def code_of(exc: pytest.ExceptionInfo[DeviceError]) -> ErrorCode:
    return ErrorCode(exc.value.code)


def pipeline(c: Client, cmds: Sequence[Command], timeout: float = 10.0) -> list[Response]:
    for cmd in cmds:
        c.send_frame(frame(cmd))
    return [c.read_response(timeout) for _ in cmds]


# -- every command ---------------------------------------------------------------------
def test_example_frame_from_protocol(client: Client) -> None:
    client.send_frame(bytes.fromhex("03 00 00 00 00 00 00 00 00 8B"))
    assert client.read_raw(5) == bytes([0x01, 0x01, 0x00, 0x00, SMBUS.compute(b"\x01\x00\x00")])


def test_moveto_wait_position(client: Client) -> None:
    assert client.is_ready(0)
    client.move_to(0, 300)
    assert not client.is_ready(0)
    client.wait_moved(0, 10_000)
    assert client.is_ready(0)
    assert client.position(0) == 300
    client.move_to(0, -250, speed=255, acc=255, dec=255)
    client.wait_moved(0, 10_000)
    assert client.position(0) == -250


def test_position_while_moving(client: Client) -> None:
    client.move(0, True, speed=1)  # 4096 step/s
    positions = [client.position(0)]

    def past_200() -> bool:
        positions.append(client.position(0))
        return positions[-1] >= 200

    until("motor 0 past 200", past_200)
    client.stop(0, hard=True)
    client.wait_moved(0, 5000)
    assert positions == sorted(positions) and positions[-1] > positions[0]
    assert client.position(0) >= positions[-1]


def test_move_change_speed_and_soft_stop(client: Client) -> None:
    client.move(1, True, speed=1)
    client.move(1, False, speed=1)  # reverses along the ramps, at once
    until("motor 1 below 0", lambda: client.position(1) < 0)
    client.stop(1, hard=False)
    client.wait_moved(1, 5000)
    assert client.position(1) < 0
    assert client.is_ready(1)


def test_init_move_homes_at_end_stop(client: Client) -> None:
    client.init_move(2, False, speed=3)  # 12,288 step/s towards the end stop at -10000
    client.wait_moved(2, 20_000)
    assert client.position(2) == 0
    client.move_to(2, 500)
    client.wait_moved(2, 10_000)
    assert client.position(2) == 500


def test_home_and_waypoints(client: Client) -> None:
    client.move_to(0, 120)
    client.wait_moved(0, 5000)
    client.save_home(0)
    assert client.save_waypoint(0) == 0
    client.move_to(0, -80)
    client.wait_moved(0, 5000)
    assert client.save_waypoint(0) == 1
    client.go_home(0)
    client.wait_moved(0, 5000)
    assert client.position(0) == 120
    client.move_to_waypoint(0, 1)
    client.wait_moved(0, 5000)
    assert client.position(0) == -80
    client.move_to_waypoint(0, 0, speed=200)
    client.wait_moved(0, 5000)
    assert client.position(0) == 120


def test_pins_wired_in_the_mock(client: Client) -> None:
    assert client.get_pin(4) is False
    client.set_pin(1, True)
    assert client.get_pin(5) is True
    assert client.get_pin(1) is True
    client.set_pin(1, False)
    assert client.get_pin(5) is False
    client.config_pin(5, True)  # turn the input into an output
    client.set_pin(5, True)
    client.config_pin(1, False)
    assert client.get_pin(1) is True  # reads what pin 5 now drives


def test_dc_move(client: Client, daemon: DaemonProcess) -> None:
    client.dc_move(True, 200, hiz=False)
    client.dc_move(False, 0, hiz=True)  # TIME 0 stops at once
    assert daemon.status()["link"]["counters"]["frames_good"] == 2


def test_queue_runs_in_order(client: Client) -> None:
    for target in (100, -100, 50):
        client.move_to(0, target)
    client.wait_moved(0, 10_000)
    assert client.position(0) == 50


# -- every error code ------------------------------------------------------------------
def test_e0_queue_full(client: Client) -> None:
    client.move(0, True, speed=1)  # runs until stopped; commands wait behind it
    for i in range(16):
        client.move_to(0, i)
    with pytest.raises(DeviceError) as exc:
        client.move_to(0, 99)
    assert code_of(exc) is E.FULL_BUFFER
    client.stop(0, hard=True)  # empties the queue
    client.wait_moved(0, 5000)
    assert client.is_ready(0)


def test_e1_bad_checksum_and_padding_not_executed(client: Client, daemon: DaemonProcess) -> None:
    good = encode_command(MoveTo(0, True, 1000, 0, 0, 0), OPTS)
    client.send_frame(good[:9] + bytes([good[9] ^ 0x55]))
    assert client.read_response().error_code is E.INVALID_COMMAND
    padded = raw_frame(bytes([0x03, 0x00, 0x07]))  # IsReady with garbage padding
    client.send_frame(padded)
    assert client.read_response().error_code is E.INVALID_COMMAND
    client.send_frame(raw_frame(bytes([0x0F, 0x00])))  # unknown code
    assert client.read_response().error_code is E.INVALID_COMMAND
    assert client.is_ready(0) and client.position(0) == 0
    counters = daemon.status()["link"]["counters"]
    assert counters["checksum_errors"] == 1
    assert counters["padding_errors"] == 1
    assert counters["unknown_errors"] == 1
    assert counters["sent_E1"] == 3


def test_e1_parameters(small: DaemonProcess) -> None:
    with small.client() as c:
        with pytest.raises(DeviceError) as exc:
            c.move_to(0, 501)  # beyond the soft limit
        assert code_of(exc) is E.INVALID_COMMAND
        with pytest.raises(DeviceError) as exc:
            c.set_pin(1, True)  # an input
        assert code_of(exc) is E.INVALID_COMMAND
        assert c.is_ready(0) and c.position(0) == 0


def test_e2_addresses(client: Client) -> None:
    for call in (
        lambda: client.is_ready(3),
        lambda: client.move_to(7, 1),
        lambda: client.get_pin(8),
        lambda: client.set_pin(200, True),
        lambda: client.position(255),
    ):
        with pytest.raises(DeviceError) as exc:
            call()
        assert code_of(exc) is E.INVALID_ADDRESS


def test_e2_no_dc_motor(small: DaemonProcess) -> None:
    with small.client() as c, pytest.raises(DeviceError) as exc:
        c.dc_move(True, 100, hiz=False)
    assert code_of(exc) is E.INVALID_ADDRESS


def test_e3_busy_and_wait_timeout(client: Client) -> None:
    client.move(0, True, speed=1)
    for call in (
        lambda: client.save_home(0),
        lambda: client.save_waypoint(0),
        lambda: client.wait_moved(0, 30),
    ):
        with pytest.raises(DeviceError) as exc:
            call()
        assert code_of(exc) is E.MOTOR_NOT_READY
    client.stop(0, hard=True)
    client.wait_moved(0, 5000)


def test_e4_end_stop_hit_latches_fault(client: Client) -> None:
    # down into the simulated end stop at -10000: wired in both worlds (a dSPIN motor's one
    # switch input, SW, is the end stop below the axis in docs/examples/dspin.toml)
    client.move(0, False, speed=2)
    with pytest.raises(DeviceError) as exc:
        client.wait_moved(0, 20_000)
    assert code_of(exc) is E.MOTOR_ERROR
    for call in (
        lambda: client.is_ready(0),
        lambda: client.move_to(0, 0),
        lambda: client.save_home(0),
    ):
        with pytest.raises(DeviceError) as exc:
            call()
        assert code_of(exc) is E.MOTOR_ERROR
    assert client.position(0) == -10_000  # GetAbsPos still answers
    client.stop(0)  # clears the fault
    assert client.is_ready(0)
    client.move_to(0, -9000)
    client.wait_moved(0, 10_000)
    assert client.position(0) == -9000


def test_e4_failed_homing(small: DaemonProcess) -> None:
    with small.client() as c:
        c.init_move(0, True)  # max_travel 300, end stop 10000 away
        with pytest.raises(DeviceError) as exc:
            c.wait_moved(0, 20_000)
        assert code_of(exc) is E.MOTOR_ERROR
        c.stop(0)
        assert c.is_ready(0)


def test_e5_waypoints_full_e6_unknown(small: DaemonProcess) -> None:
    with small.client() as c:
        with pytest.raises(DeviceError) as exc:
            c.move_to_waypoint(0, 0)
        assert code_of(exc) is E.INVALID_WAYPOINT
        assert [c.save_waypoint(0), c.save_waypoint(0)] == [0, 1]
        with pytest.raises(DeviceError) as exc:
            c.save_waypoint(0)
        assert code_of(exc) is E.FULL_WAYPOINT_BUFFER
        with pytest.raises(DeviceError) as exc:
            c.move_to_waypoint(0, 2)
        assert code_of(exc) is E.INVALID_WAYPOINT


def test_queue_depth_from_config(small: DaemonProcess) -> None:
    with small.client() as c:
        c.move(0, True, speed=1)  # stops at the soft limit 500
        c.move_to(0, 0)
        c.move_to(0, 10)
        with pytest.raises(DeviceError) as exc:
            c.move_to(0, 20)
        assert code_of(exc) is E.FULL_BUFFER
        c.wait_moved(0, 10_000)
        assert c.position(0) == 10


def test_rotary_axis_wraps(small: DaemonProcess) -> None:
    with small.client() as c:
        c.move_to(1, 300, direction=False)  # from 0 down to 300: 100 steps
        c.wait_moved(1, 5000)
        assert c.position(1) == 300
        c.move_to(1, 100, direction=True)  # up through 0: 200 steps
        c.wait_moved(1, 5000)
        assert c.position(1) == 100


# -- framing ---------------------------------------------------------------------------
def test_gap_discard(client: Client, daemon: DaemonProcess) -> None:
    partial = encode_command(MoveTo(0, True, 500, 0, 0, 0), OPTS)[:5]
    client.send_bytes(partial)
    assert client.read_raw(1, timeout=0.1) == b""  # an incomplete frame gets no response
    # The gap itself: silence until the daemon has watched frame_gap_ms (10 ms) pass.
    until("the gap discard", lambda: daemon.status()["link"]["counters"]["gap_discards"] == 1)
    client.send_frame(frame(IsReady(0)))
    assert client.read_response().as_bool is True
    assert client.position(0) == 0
    assert daemon.status()["link"]["counters"]["gap_discards"] == 1


def test_split_frames_within_gap(tmp_path: Path) -> None:
    # A 500 ms gap: a loaded machine may pause this process for tens of ms between writes,
    # which would be a real gap on the line at 10 ms.
    d = DaemonProcess(tmp_path, "[link]\nframe_gap_ms = 500.0\n" + SMALL).start()
    try:
        with d.client() as c:
            data = encode_command(GetAbsPos(0), OPTS) + encode_command(IsReady(0), OPTS)
            for i in range(0, len(data), 3):
                c.send_bytes(data[i : i + 3])
            assert c.read_response().as_position == 0
            assert c.read_response().as_bool is True
        assert d.status()["link"]["counters"]["gap_discards"] == 0
    finally:
        d.close()


# -- WaitMoved holds the link ------------------------------------------------------------
def test_wait_moved_held_with_stop_behind_it(client: Client) -> None:
    client.move(0, True, speed=1)
    until("motor 0 moving", lambda: client.position(0) != 0)
    responses = pipeline(
        client, [WaitMoved(0, 20_000), IsReady(1), StopMove(0, True), GetAbsPos(0), IsReady(0)]
    )
    assert [r.ack for r in responses] == [True] * 5
    assert responses[1].as_bool is True
    stopped_at = responses[3].as_position
    assert stopped_at > 0
    assert responses[4].as_bool is True
    assert client.position(0) == stopped_at


def test_held_frames_overflow_gets_e0_in_turn_but_a_stop_is_never_refused(client: Client) -> None:
    client.move(0, True, speed=1)
    # 1 WaitMoved, 18 frames behind it, then a StopMove as the 20th: 16 are kept, the next
    # 2 get E0 in their turn and are not executed; the StopMove is executed on arrival
    # although the buffer is full, which ends the WaitMoved (ACK), and answered in its turn.
    cmds: list[Command] = [WaitMoved(0, 20_000), *[IsReady(1)] * 18, StopMove(0, True), IsReady(0)]
    answers = pipeline(client, cmds)
    assert answers[0].ack
    assert all(a.ack and a.as_bool for a in answers[1:17])
    assert all(a.error_code is E.FULL_BUFFER for a in answers[17:19])
    assert answers[19].ack
    assert answers[20].as_bool is True
    assert client.is_ready(0) is True


def test_a_bad_frame_takes_its_place_among_the_16_held_frames(client: Client) -> None:
    # PROTOCOL.md §4 exempts only StopMove from the 16 places: behind WaitMoved(0, 600),
    # 4 GetAbsPos, a frame with a bad checksum, IsReady(77) and 10 GetAbsPos, the SetPin is
    # the 17th kept frame: E0 in its turn, and pin 2 stays low.
    client.move(0, True, speed=1)
    until("motor 0 moving", lambda: client.position(0) != 0)
    bad = bytearray(encode_command(GetAbsPos(1), OPTS))
    bad[9] ^= 0x55
    behind: list[Command] = [IsReady(77), *[GetAbsPos(0)] * 10, SetPin(2, True)]
    before: list[Command] = [WaitMoved(0, 600), *[GetAbsPos(0)] * 4]
    data = b"".join(encode_command(c, OPTS) for c in before)
    client.send_bytes(data + bytes(bad) + b"".join(encode_command(c, OPTS) for c in behind))
    answers = [client.read_response(10.0) for _ in range(18)]
    assert [a.error_code for a in answers] == (
        [E.MOTOR_NOT_READY]
        + [None] * 4
        + [E.INVALID_COMMAND, E.INVALID_ADDRESS]
        + [None] * 10
        + [E.FULL_BUFFER]
    )
    assert client.get_pin(2) is False
    client.stop(0, True)


def test_wait_moved_reports_fault(client: Client) -> None:
    client.move(2, False, speed=2)
    responses = pipeline(client, [WaitMoved(2, 20_000), GetAbsPos(2)], timeout=25.0)
    assert responses[0].error_code is E.MOTOR_ERROR
    assert responses[1].as_position == -10_000


# -- persistence -------------------------------------------------------------------------
def test_home_and_waypoints_survive_restart(tmp_path: Path) -> None:
    d = DaemonProcess(tmp_path).start()
    with d.client() as c:
        c.move_to(0, 200)
        c.wait_moved(0, 5000)
        c.save_home(0)
        c.move_to(0, -100)
        c.wait_moved(0, 5000)
        assert c.save_waypoint(0) == 0
    assert d.terminate() == 0
    d2 = DaemonProcess(tmp_path, state_dir=d.state_dir).start()
    try:
        with d2.client() as c:
            assert c.position(0) == -100
            c.go_home(0)
            c.wait_moved(0, 5000)
            assert c.position(0) == 200
            c.move_to_waypoint(0, 0)
            c.wait_moved(0, 5000)
            assert c.position(0) == -100
            assert c.save_waypoint(0) == 1
    finally:
        d2.close()


def running_daemon(tmp_path: Path) -> DaemonProcess:
    """A daemon whose motor 0 is running continuously, already past position 100."""
    d = DaemonProcess(tmp_path).start()
    with d.client() as c:
        c.move(0, True, speed=1)
        until("motor 0 past 100", lambda: c.position(0) >= 100)
    return d


def test_sigterm_stops_motors_along_ramps(tmp_path: Path) -> None:
    d = running_daemon(tmp_path)
    assert d.terminate() == 0
    first = d.stderr()  # the next daemon writes its log in the same place
    assert "position lost" not in first, first
    d2 = DaemonProcess(tmp_path, state_dir=d.state_dir).start()
    try:
        with d2.client() as c:
            pos = c.position(0)
            assert pos > 100
            c.move_to(0, 0)  # position still known: accepted
            c.wait_moved(0, 10_000)
            assert c.position(0) == 0
    finally:
        d2.close()


@pytest.mark.stepdir
def test_sigterm_to_the_whole_service_stops_motors_along_ramps(tmp_path: Path) -> None:
    """systemd's stop sends SIGTERM to every process of the unit: the step executor process
    must leave the stop to the daemon, or every stop would lose every position."""
    d = running_daemon(tmp_path)
    assert d.proc is not None
    children = Path(f"/proc/{d.proc.pid}/task/{d.proc.pid}/children").read_text().split()
    assert children, "the default (process) executor runs in a child process"
    for pid in [d.proc.pid, *map(int, children)]:
        os.kill(pid, signal.SIGTERM)
    assert d.proc.wait(20) == 0
    assert "died" not in d.stderr()
    d2 = DaemonProcess(tmp_path, state_dir=d.state_dir).start()
    try:
        with d2.client() as c:
            assert c.position(0) > 100
            c.move_to(0, 0)  # position still known: accepted
            c.wait_moved(0, 10_000)
            assert c.position(0) == 0
    finally:
        d2.close()


def test_killed_while_moving_loses_position(tmp_path: Path) -> None:
    d = running_daemon(tmp_path)
    d.kill()
    d2 = DaemonProcess(tmp_path, state_dir=d.state_dir).start()
    try:
        with d2.client() as c:
            calls: list[Callable[[], None]] = [
                lambda: c.move_to(0, 0),
                lambda: c.move(0, True),
                lambda: c.go_home(0),
            ]
            for call in calls:
                with pytest.raises(DeviceError) as exc:
                    call()
                assert code_of(exc) is E.MOTOR_ERROR
            assert c.is_ready(0)
            c.init_move(0, False, speed=3)  # 12,288 step/s: the end stop at -10000 in 1.6 s
            c.wait_moved(0, 20_000)
            assert c.position(0) == 0
            c.move_to(0, 10)
            c.wait_moved(0, 5000)
            assert c.position(0) == 10
            c.move_to(1, 5)  # other motors were at rest: unaffected
            c.wait_moved(1, 5000)
    finally:
        d2.close()


# -- both step executors, and the executor's death ----------------------------------------
@pytest.mark.stepdir
def test_the_thread_executor_end_to_end(tmp_path: Path) -> None:
    from motorctl.daemon.config import default_config_text
    from tests.support.daemon_proc import for_tests

    text = for_tests(default_config_text(), force=True)
    d = DaemonProcess(tmp_path, text.replace('executor = "process"', 'executor = "thread"'))
    d.start()
    try:
        assert d.status()["executor"]["kind"] == "thread"
        assert d.status()["executor"]["core"] == "python"  # the thread kind keeps it
        assert "; step core python;" in d.ready_line
        assert d.proc is not None  # motorctld started an executor process early: ended
        assert children_of(d.proc.pid) == []
        with d.client() as c:
            c.move_to(0, 300)
            c.move_to(1, -200)
            c.wait_moved(0, 10_000)
            c.wait_moved(1, 10_000)
            assert (c.position(0), c.position(1)) == (300, -200)
            c.init_move(2, False, speed=2)  # homing: the end stop at -10000 stops it
            c.wait_moved(2, 20_000)  # and one step back up releases it: zero there
            assert c.position(2) == 0
        steps = d.status()["steps"]
        assert steps["steps"] == 500 + 10_000 + 1 and steps["timing_lost"] == 0
    finally:
        assert d.terminate() == 0


@pytest.mark.stepdir
def test_the_executor_process_dying_faults_every_motor_and_stops_the_daemon(
    daemon: DaemonProcess,
) -> None:
    import os
    import signal
    import time

    status = daemon.status()
    assert status["executor"]["kind"] == "process" and status["executor"]["alive"]
    assert status["executor"]["core"] == "compiled"  # where it is built: the default
    assert "; mock hardware; step core compiled; state in " in daemon.ready_line
    assert daemon.proc is not None
    assert children_of(daemon.proc.pid) == [status["executor"]["pid"]]  # no tracker
    blocks = memfd_labels(daemon.proc.pid)
    assert len(blocks) == 2  # the executor's block, the mock's mechanics
    with daemon.client() as c:
        c.move(0, True, speed=1)
        until_moving = time.monotonic() + 10
        while c.position(0) < 100:
            assert time.monotonic() < until_moving
        os.kill(status["executor"]["pid"], signal.SIGKILL)
        deadline = time.monotonic() + 5
        while True:  # answers go on for a grace period: E4 on every motor
            try:
                c.is_ready(0)
            except DeviceError as exc:
                assert code_of_error(exc) is E.MOTOR_ERROR
                break
            assert time.monotonic() < deadline, "no E4 after the executor died"
        for m in range(3):
            with pytest.raises(DeviceError) as info:
                c.is_ready(m)
            assert code_of(info) is E.MOTOR_ERROR
        st = daemon.status()
        assert not st["executor"]["alive"] and "died" in st["executor"]["reason"]
        assert all(m["position_lost"] and "died" in m["fault"] for m in st["motors"])
    # exits non-zero for the service manager to restart, after the grace period and without
    # waiting for stops that a dead executor can never confirm (SHUTDOWN_LIMIT_S)
    assert daemon.proc.wait(EXECUTOR_DEATH_GRACE_S + SHUTDOWN_LIMIT_S - 2) == 3
    assert "step executor" in daemon.stderr() and "died" in daemon.stderr()
    assert memfd_holders(blocks) == []  # the shared memory is gone with both processes


def code_of_error(exc: DeviceError) -> ErrorCode:
    return ErrorCode(exc.code)


@pytest.mark.stepdir
def test_status_has_the_step_lateness_histogram(daemon: DaemonProcess) -> None:
    """bench/steps.py reads the executor's 1 us lateness histogram from the status."""
    with daemon.client() as c:
        c.move_to(0, 300)
        c.wait_moved(0, 10_000)
    assert "histogram_us" not in daemon.status()["steps"]  # only when asked: it can be big
    steps = daemon.status(histogram=True)["steps"]
    histogram = {int(us): n for us, n in steps["histogram_us"].items()}
    assert sum(histogram.values()) == steps["steps"] >= 300
    cli = [
        sys.executable,
        "-m",
        "motorctl.daemon.start.main",
        "--state-dir",
        str(daemon.state_dir),
        "--status",
    ]
    run = subprocess.run([*cli, "--histogram"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    printed = json.loads(run.stdout)["steps"]
    assert printed["histogram_us"] == steps["histogram_us"]
    for key in ("ring_retries_segments", "ring_retries_reports"):  # the process executor's
        assert isinstance(printed[key], int) and printed[key] >= 0, key
    run = subprocess.run([*cli[:-1], "--histogram"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "--histogram goes with --status" in run.stderr


# -- lateness as the motor would feel it ---------------------------------------------------
def _stall_mid_move(d: DaemonProcess, c: Client) -> None:
    """MoveTo 1500 at 1,000 step/s on motor 0; once it is under way, the executor process is
    stopped for 50 ms (a platform stall): 3 full steps of lag at 16 microsteps. (On a loaded
    machine a daemon whose steps fault on lag may fault before: a step of its own came late
    enough. That is the same fault, and the stall then changes nothing.)"""
    pid = d.status()["executor"]["pid"]
    c.move_to(0, 1500, speed=250)  # 250 x 4 step/s
    until(
        "motor 0 under way",
        lambda: c.position(0) > 300 or d.status()["motors"][0]["fault"] is not None,
    )
    os.kill(pid, signal.SIGSTOP)
    try:
        threading.Event().wait(0.05)  # the stall itself
    finally:
        os.kill(pid, signal.SIGCONT)


@pytest.mark.stepdir
def test_the_embedded_default_slides_a_stalled_move_and_shows_it(daemon: DaemonProcess) -> None:
    """The simulated motors have no rotor: a 50 ms stall of the executor never answers E4;
    the move reaches its target late, and the status shows the step absorbed, how late and
    the lag a real motor would have felt."""
    with daemon.client() as c:
        _stall_mid_move(daemon, c)
        c.wait_moved(0, 20_000)  # an ACK, not E4
        assert c.position(0) == 1500 and c.is_ready(0)
    m = daemon.status()["motors"][0]
    assert m["fault"] is None and not m["position_lost"] and m["faults"] == {}
    timing = m["timing"]
    assert timing["late_absorbed"] >= 1 and timing["lag_faults"] == 0
    assert timing["worst_late_us"] >= 40_000 and timing["slid_ms"] >= 40
    assert timing["worst_lag_full_steps"] >= 0.04 * 1000 / 16
    assert (timing["microsteps"], timing["max_lag_full_steps"]) == (16, 0.5)


@pytest.mark.stepdir
def test_with_lose_steps_the_mock_faults_as_a_real_motor_would(tmp_path: Path) -> None:
    """[mock] lose_steps = true: the same stall is beyond 0.5 full steps of lag above the
    start speed: E4 "step timing lost", position lost (home again), one journal line with
    the figures, counted under its cause."""
    from motorctl.daemon.config import default_config_text
    from tests.support.daemon_proc import for_tests

    text = for_tests(default_config_text(), force=True)
    assert "lose_steps = false" in text
    d = DaemonProcess(tmp_path, text.replace("lose_steps = false", "lose_steps = true")).start()
    try:
        with d.client() as c:
            _stall_mid_move(d, c)
            with pytest.raises(DeviceError) as info:
                c.wait_moved(0, 20_000)
            assert code_of(info) is E.MOTOR_ERROR
            m = d.status()["motors"][0]
            assert m["fault"].startswith("step timing lost") and "full steps" in m["fault"]
            assert m["position_lost"] and m["faults"] == {"timing_lost": 1}
            assert m["timing"]["lag_faults"] == 1
            c.stop(0)  # clears the fault; the position stays lost until homed
            with pytest.raises(DeviceError) as info:
                c.move_to(0, 0)
            assert code_of(info) is E.MOTOR_ERROR
        until("the journal line", lambda: "fault latched: step timing lost" in d.stderr())
        line = next(x for x in d.stderr().splitlines() if "fault latched" in x)
        assert "motor 0 (x)" in line and "lag" in line and "position lost" in line
    finally:
        d.close()
