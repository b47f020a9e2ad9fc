"""The service end to end, as real processes on a real PTY: one instance, SIGHUP, bad state
files, a read-only state directory, PTY permissions, kill -9 right after a motion's ACK,
and systemd's notifications on a fake NOTIFY_SOCKET."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from motorctl.client.client import DeviceError
from motorctl.daemon.start.serve import EXIT_STATE_NOT_SAVED
from motorctl.protocol.codec import ErrorCode
from tests.support.daemon_proc import DaemonProcess, StartDaemon
from tests.support.fsutil import fill, read_only, small_tmpfs
from tests.support.wait import until

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

E = ErrorCode
DEADLINE_S = 20.0


@pytest.fixture
def daemon(motorctld: StartDaemon) -> DaemonProcess:
    return motorctld()


def no_traceback(d: DaemonProcess) -> None:
    assert "Traceback" not in d.stderr(), d.stderr()


def test_second_daemon_exits_at_once_naming_the_first(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    assert daemon.proc is not None
    target = os.readlink(daemon.pty)
    second = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--pty",
            str(daemon.pty),
            "--state-dir",
            str(daemon.state_dir),
        ],
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
    )
    assert second.returncode == 1
    assert f"another motorctld (PID {daemon.proc.pid})" in second.stderr
    assert "Traceback" not in second.stderr
    # Another state dir, same PTY: refused too, by the PTY's lock.
    third = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--pty",
            str(daemon.pty),
            "--state-dir",
            str(tmp_path / "other"),
        ],
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
    )
    assert third.returncode == 1 and f"PID {daemon.proc.pid}" in third.stderr
    assert "PTY" in third.stderr
    # The first is untouched and reachable.
    assert os.readlink(daemon.pty) == target
    with daemon.client() as c:
        assert c.position(0) == 0
    assert "motors" in daemon.status()
    assert daemon.terminate() == 0
    for name in ("status.sock", "motorctld.lock"):
        assert not (daemon.state_dir / name).exists(), name
    assert not daemon.pty.is_symlink()
    assert not (tmp_path / ".motorctl.pty.lock").exists()


def test_sighup_stops_cleanly_and_keeps_state(daemon: DaemonProcess, tmp_path: Path) -> None:
    with daemon.client() as c:
        c.move_to(0, 321)
        c.wait_moved(0, 5000)
    assert daemon.proc is not None
    daemon.proc.send_signal(signal.SIGHUP)
    assert daemon.proc.wait(DEADLINE_S) == 0
    assert "SIGHUP" in daemon.stderr() and "stopping as for SIGTERM" in daemon.stderr()
    no_traceback(daemon)
    assert not daemon.pty.is_symlink()
    d2 = DaemonProcess(tmp_path, state_dir=daemon.state_dir).start()
    try:
        with d2.client() as c:
            assert c.position(0) == 321
    finally:
        d2.close()


def test_pty_is_0660_with_the_daemons_group(daemon: DaemonProcess) -> None:
    st = os.stat(daemon.pty)
    assert stat.S_IMODE(st.st_mode) == 0o660
    assert st.st_gid == os.getegid()


@pytest.mark.parametrize("kind", ["bad bytes", "directory"])
def test_bad_state_file_starts_with_every_motor_lost(tmp_path: Path, kind: str) -> None:
    state = tmp_path / "state"
    state.mkdir()
    if kind == "directory":
        (state / "state.json").mkdir()
    else:
        (state / "state.json").write_bytes(b"\xff\xfe{")
    d = DaemonProcess(tmp_path, state_dir=state).start()
    try:
        assert "every motor must be homed again" in d.stderr()
        assert (state / "state.json.bad").exists()
        with d.client() as c:
            with pytest.raises(DeviceError) as exc:
                c.move_to(0, 10)
            assert exc.value.code == E.MOTOR_ERROR
            c.init_move(0, False, speed=3)  # 12,288 step/s: the end stop at -10000 in 1.6 s
            c.wait_moved(0, 20_000)
            c.move_to(0, 10)  # homed: position known again
        assert "nothing restored" in d.status()["state"]["restored"]
    finally:
        d.close()
    no_traceback(d)


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_whatever_stands_at_the_state_file_is_set_aside_under_a_free_name(
    tmp_path: Path, kind: str
) -> None:
    # Issue 16: a directory at state.json while a state.json.bad file already existed left
    # the daemon unable to write any state: InitMove E4 for ever, MoveToWayPoint(0, 0) E4
    # instead of E6, SIGTERM exit 4. (A FIFO there blocked the start for ever.)
    state = tmp_path / "state"
    state.mkdir()
    (state / "state.json.bad").write_text("an older one")
    if kind == "directory":
        (state / "state.json").mkdir()
        (state / "state.json" / "junk").write_text("x")
    else:
        os.mkfifo(state / "state.json")
    d = DaemonProcess(tmp_path, state_dir=state).start()
    try:
        with d.client() as c:
            with pytest.raises(DeviceError) as exc:
                c.move_to_waypoint(0, 0)
            assert exc.value.code == E.INVALID_WAYPOINT
            c.init_move(0, False, speed=6)  # a lost motor can be homed: accepted
            assert not c.is_ready(0)
            c.stop(0, True)
        assert f"{state / 'state.json'} is a {kind.replace('fifo', 'FIFO')}" in d.stderr()
        assert f"kept it as {state / 'state.json.bad.1'}" in d.stderr()
        assert d.status()["state"]["ok"] is True
        assert d.terminate() == 0
    finally:
        d.close()
    no_traceback(d)
    assert (state / "state.json.bad").read_text() == "an older one"
    assert os.path.lexists(state / "state.json.bad.1")
    assert json.loads((state / "state.json").read_text())["version"] == 2


def _state_file(state: Path, motors: list[dict[str, object]]) -> bytes:
    from motorctl.daemon.config import parse_config
    from motorctl.daemon.start.assemble import motor_identities
    from tests.support.daemon_proc import world_config_text

    # the motors of the world the test daemon serves (their fingerprints say their drivers)
    idents = motor_identities(parse_config(world_config_text(), "default"))
    records = [
        {
            "name": i.name,
            "fingerprint": i.fingerprint,
            "position": 0,
            "home": 0,
            "waypoints": [],
            "moving": False,
            "position_lost": False,
        }
        for i in idents
    ]
    for record, change in zip(records, motors, strict=False):
        record.update(change)
    records += [dict(records[0], **m) for m in motors[len(idents) :]]
    data = json.dumps({"version": 2, "motors": records}).encode()
    state.mkdir()
    (state / "state.json").write_bytes(data)
    return data


@pytest.mark.parametrize("change", ["motor q", "position", "256 waypoints"])
def test_a_state_file_restores_motor_by_motor(tmp_path: Path, change: str) -> None:
    # PROTOCOL.md §4: an inconsistent file restores nothing for the motors concerned, and
    # is kept aside. A motor the config does not have (x, y, z and a "q") was silently
    # dropped; one bad value in y's record lost x and z too.
    y: dict[str, object] = {"position": 200, "home": 3, "waypoints": [5]}
    if change == "position":
        y["position"] = 1 << 23
    elif change == "256 waypoints":
        y["waypoints"] = list(range(256))
    motors: list[dict[str, object]] = [{"position": 100}, y, {"position": 300}]
    if change == "motor q":
        motors.append({"name": "q", "position": 4})
    state = tmp_path / "state"
    data = _state_file(state, motors)
    d = DaemonProcess(tmp_path, state_dir=state).start()
    try:
        with d.client() as c:
            assert (c.position(0), c.position(2)) == (100, 300)
            if change == "motor q":
                assert c.position(1) == 200
                c.move_to_waypoint(1, 0)
                c.wait_moved(1, 5000)
                assert c.position(1) == 5
                assert "has motor 'q', which the config does not have" in d.stderr()
            else:
                with pytest.raises(DeviceError) as exc:
                    c.move_to(1, 0)
                assert exc.value.code == E.MOTOR_ERROR
                assert "motor 1 (y): nothing restored" in d.stderr()
            c.move_to(0, 0)  # x's position is known
            c.wait_moved(0, 5000)
        assert (state / "state.json.bad").read_bytes() == data
        assert "the file was kept as" in d.status()["state"]["restored"]
    finally:
        d.close()
    no_traceback(d)


def test_read_only_state_dir_while_running(daemon: DaemonProcess) -> None:
    with daemon.client() as c:
        c.move_to(0, 50)
        c.wait_moved(0, 5000)
        assert c.save_waypoint(0) == 0
        with read_only(daemon.state_dir):
            with pytest.raises(DeviceError) as exc:
                c.save_waypoint(0)
            assert exc.value.code == E.MOTOR_ERROR  # never "saved" for what is not
            with pytest.raises(DeviceError):
                c.save_home(0)
            state = daemon.status()["state"]
            assert state["ok"] is False and "Read-only" in state["last_error"]
            # shutdown with an unwritable directory: says so, and exits non-zero
            assert daemon.terminate() == EXIT_STATE_NOT_SAVED
    no_traceback(daemon)
    assert "cannot write state file" in daemon.stderr()
    assert "stopped WITHOUT saving the final state (cannot write state file" in daemon.stderr()
    assert not daemon.pty.is_symlink()


def _not_main_thread(pid: int) -> int:
    tids = sorted(int(t) for t in os.listdir(f"/proc/{pid}/task") if int(t) != pid)
    assert tids, "motorctld runs more threads than its main one"
    return tids[0]


@pytest.mark.parametrize("state_dir", ["writable", "read-only"])
def test_sigterm_taken_by_another_thread_stops_an_idle_daemon_with_the_port_open(
    daemon: DaemonProcess, state_dir: str
) -> None:
    """kill(2) of a thread's ID hands the signal to that thread: its C handler runs there
    and the main thread's poll() is not interrupted (as for a signal that arrives just
    before that poll()). The host keeps the port open and idle, so that poll() has no
    timeout: only the signal wake-up descriptor can end it. Without one the daemon ran on
    until the host's next byte (the once-flaky test_read_only_state_dir_while_running)."""
    assert daemon.proc is not None
    unwritable = (
        read_only(daemon.state_dir) if state_dir == "read-only" else contextlib.nullcontext()
    )
    with daemon.client() as c:
        c.move_to(0, 50)
        c.wait_moved(0, 5000)
        with unwritable:
            assert c.position(0) == 50  # the link loop then sleeps in poll(), no timeout
            os.kill(_not_main_thread(daemon.proc.pid), signal.SIGTERM)
            try:
                code = daemon.proc.wait(DEADLINE_S)
            except subprocess.TimeoutExpired:
                raise AssertionError(
                    f"motorctld still runs {DEADLINE_S} s after a SIGTERM: {daemon.stderr()}"
                ) from None
    assert code == (0 if state_dir == "writable" else EXIT_STATE_NOT_SAVED)
    assert "SIGTERM: stopping" in daemon.stderr()
    no_traceback(daemon)
    assert not daemon.pty.is_symlink()


def test_kill_right_after_a_motion_ack_loses_the_position(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    with daemon.client() as c:
        c.move_to(0, 100)
        c.wait_moved(0, 5000)
        c.move_to(0, 5000, speed=1)  # ACKed: "moving" is on disk already
    daemon.kill()
    d2 = DaemonProcess(tmp_path, state_dir=daemon.state_dir).start()
    try:
        assert "was moving when the daemon stopped" in d2.stderr()
        with d2.client() as c, pytest.raises(DeviceError) as exc:
            c.move_to(0, 0)
        assert exc.value.code == E.MOTOR_ERROR
    finally:
        d2.close()


def test_kill_right_after_a_move_of_no_distance_keeps_the_idle_motor(tmp_path: Path) -> None:
    # Issue 16: MoveTo(2, 777) with motor 2 at 777 (here 77: a shorter first move), ACK,
    # WaitMoved ACK, IsReady 1, then a MoveTo on motor 0 and a kill -9: after the restart
    # motor 2 answered E4, "motor 0 (x), 2 (z) was moving". Its journal byte stayed set
    # until the writer's next durable state write; a full state directory (as here) holds
    # that write off for good, so the kill comes before it every time.
    with small_tmpfs(tmp_path / "state") as state:
        d = DaemonProcess(tmp_path, state_dir=state).start()
        with d.client() as c:
            c.move_to(2, 77)
            c.wait_moved(2, 5000)
            until(
                "motor 2 at rest on disk", lambda: (state / "state.moving").read_bytes() == b"000"
            )
            filler = fill(state)
            c.move_to(2, 77)  # no distance
            c.wait_moved(2, 5000)
            assert c.is_ready(2)
            c.move_to(0, 5000, speed=1)
        d.kill()
        filler.unlink()
        d2 = DaemonProcess(tmp_path, state_dir=state).start()
        try:
            with d2.client() as c:
                assert c.position(2) == 77
                c.move_to(2, 0)  # its position is known
                c.wait_moved(2, 5000)
                with pytest.raises(DeviceError) as exc:
                    c.move_to(0, 0)  # motor 0 really moved: lost
                assert exc.value.code == E.MOTOR_ERROR
            assert "motor 0 (x) was moving when the daemon stopped" in d2.stderr()
        finally:
            d2.close()
    no_traceback(d2)


def test_notifications_on_a_fake_notify_socket(tmp_path: Path) -> None:
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(str(path))
        sock.settimeout(DEADLINE_S)
        d = DaemonProcess(tmp_path, env={"NOTIFY_SOCKET": str(path)}).start()
        try:
            seen: list[str] = []

            def wait_for(prefix: str) -> str:
                while True:
                    try:
                        msg = sock.recv(4096).decode()
                    except TimeoutError:
                        raise AssertionError(f"no {prefix} in {DEADLINE_S} s: {seen}") from None
                    seen.append(msg)
                    if msg.startswith(prefix):
                        return msg

            wait_for("READY=1")
            assert "0 moving" in wait_for("STATUS=")
            with d.client() as c:
                c.move(0, True, speed=1)
                assert "1 moving" in wait_for("STATUS=")
            assert d.terminate() == 0
            wait_for("STOPPING=1")
        finally:
            d.close()


def test_a_held_uart_names_its_holder(tmp_path: Path) -> None:
    """A UART (here a PTY's slave, opened like a serial device) flocked by someone else."""
    import fcntl

    master, slave = os.openpty()
    device = os.ttyname(slave)
    holder = os.open(device, os.O_RDWR | os.O_NOCTTY)
    fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what pyserial's exclusive=True takes
    try:
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "motorctl.daemon.start.main",
                "--port",
                device,
                "--state-dir",
                str(tmp_path / "state"),
            ],
            capture_output=True,
            text=True,
            timeout=DEADLINE_S,
        )
    finally:
        for fd in (holder, slave, master):
            os.close(fd)
    assert out.returncode == 1, out.stderr
    assert f"serial device {device} is held by another process (PID {os.getpid()})" in out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "state" / "motorctld.lock").exists()  # released on the way out
