"""motorctl as a user runs it (a process) against motorctld on a real PTY: error answers
printed with the daemon's reason, read from its status socket as `make run` and the service
lay it out, or the code's meaning when the socket is not there; the reason of a latched
fault and what clears it; Ctrl-C during a wait, which leaves the motor moving and says so;
the journal's rate limit under a flood of bad frames; the port's errors (permission and busy
as user nobody)."""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import signal
import subprocess
import sys
import termios
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.refusals import BURST
from motorctl.protocol.codec import IsReady
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess
from tests.support.frames import frame
from tests.support.fsutil import need_checkout_open_to_others
from tests.support.inprocess import Host
from tests.support.wait import until

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

TIMEOUT_S = 60.0

CONFIG = """
[[motors]]
name = "x"
soft_limit_min = -5000
soft_limit_max = 5000
[motors.mock]
endstop_min = -1500
endstop_max = 1500
[[pins]]
number = 0
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """As `make run` lays it out: the PTY ./motorctl.pty, the state in ./.run/state."""
    workdir = tmp_path_factory.mktemp("cli")
    d = DaemonProcess(workdir, CONFIG, state_dir=workdir / ".run" / "state")
    d.start()
    yield d
    d.close()


def motorctl(
    *args: str, cwd: Path = REPO, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "motorctl.client.cli", *args],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=cwd,
        env={**os.environ, **(env or {})},
    )


def quoted(where: Path, text: str) -> bool:
    """``text`` is quoted in the page ``where`` (lines may break anywhere in a quote)."""
    return " ".join(text.split()) in " ".join(where.read_text(encoding="utf-8").split())


README = REPO / "README.md"


def error_of(out: subprocess.CompletedProcess[str]) -> str:
    assert out.returncode == 1, (out.stdout, out.stderr)
    assert out.stdout == ""
    return out.stderr.strip()


def test_errors_are_printed_with_the_daemons_reason(daemon: DaemonProcess) -> None:
    here = {"MOTORCTL_PORT": "motorctl.pty"}  # as the README's walkthrough: its folder
    cases = [
        (("moveto", "5", "0"), "E2 invalid address: no motor 5 (this machine has motors 0)"),
        (("dc", "forward", "100"), "E2 invalid address: no DC motor configured"),
        (
            ("moveto", "0", "6000"),
            "E1 invalid command: target 6000 is outside the soft limits -5000..5000 (motor 0)",
        ),
        (
            ("pin", "set", "3", "high"),
            "E2 invalid address: no pin 3 (this machine has pins 0)",
        ),
    ]
    for args, text in cases:
        assert error_of(motorctl(*args, cwd=daemon.workdir, env=here)) == f"error: {text}"
    # from anywhere: the socket is found beside the port the path names
    out = motorctl("-p", str(daemon.pty), "moveto", "7", "0", env={"MOTORCTL_STATE_DIR": ""})
    assert error_of(out) == "error: E2 invalid address: no motor 7 (this machine has motors 0)"


def test_without_the_status_socket_the_codes_meaning(daemon: DaemonProcess, tmp_path: Path) -> None:
    """Elsewhere (no socket where the client looks: an empty state dir named): what the code
    means for that command, at once, never a hang or a failure."""
    env = {"MOTORCTL_STATE_DIR": str(tmp_path)}
    cases = [
        (("moveto", "5", "0"), "E2 invalid address: no motor 5"),
        (("dc", "forward", "100"), "E2 invalid address: no DC motor configured"),
        (
            ("moveto", "0", "6000"),
            "E1 invalid command: target 6000 is outside motor 0's soft limits or its driver "
            "chip's range",
        ),
    ]
    for args, text in cases:
        out = motorctl("-p", str(daemon.pty), *args, env=env)
        assert error_of(out) == f"error: {text}"
    assert quoted(README, f"`error: {cases[0][1]}`")


def test_a_latched_fault_says_what_latched_it_and_how_to_clear_it(
    daemon: DaemonProcess,
) -> None:
    port = ("-p", str(daemon.pty))
    assert motorctl(*port, "move", "0", "down", "--speed", "1").returncode == 0
    text = error_of(motorctl(*port, "wait", "0", "20000"))
    found = re.fullmatch(
        r"error: E4 motor error: end stop hit at (-\d+) outside homing \(motor 0\) — "
        r"clear it with 'motorctl stop 0'",
        text,
    )
    assert found is not None, text
    assert -1600 < int(found.group(1)) <= -1500
    assert error_of(motorctl(*port, "ready", "0")) == text  # the same fault, still latched
    assert motorctl(*port, "stop", "0").returncode == 0
    assert motorctl(*port, "ready", "0").stdout == "motor 0 ready\n"


def sigint_as_in_a_terminal() -> None:
    """In the child, before its exec: SIGINT's default disposition, as a terminal's
    foreground program has it. A test run started in the background (``make test &``)
    has SIGINT ignored, the child would inherit that, and Python leaves an ignored SIGINT
    ignored: Ctrl-C could not be what the test is about."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_during_wait_says_the_motor_keeps_moving(daemon: DaemonProcess) -> None:
    port = ("-p", str(daemon.pty))
    assert motorctl(*port, "moveto", "0", "1000", "--speed", "25").returncode == 0  # 100 step/s
    wait = subprocess.Popen(
        [sys.executable, "-m", "motorctl.client.cli", *port, "wait", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=sigint_as_in_a_terminal,
    )
    try:
        until("the WaitMoved held by the daemon", lambda: daemon.status()["link"]["waiting"])
        wait.send_signal(signal.SIGINT)
        _, err = wait.communicate(timeout=TIMEOUT_S)
    finally:
        if wait.poll() is None:
            wait.kill()
            wait.wait()
    assert wait.returncode == 130
    assert err == (
        "interrupted: motor 0 keeps moving (only the wait ended); stop it with "
        "'motorctl stop 0' ('--hard' for at once)\n"
    )
    assert quoted(README, f"`{err.strip()}`")
    first = daemon.status()["motors"][0]
    assert first["state"] == "moving"
    until(
        "motor 0 still moving after the wait was interrupted",
        lambda: daemon.status()["motors"][0]["position"] > first["position"],
    )
    assert motorctl(*port, "stop", "0", "--hard").returncode == 0
    assert daemon.status()["motors"][0]["state"] == "idle"


def test_a_flood_of_bad_frames_writes_a_burst_to_the_journal(tmp_path: Path) -> None:
    """200 bad frames in one write: 200 answers E1, BURST journal lines for the link, the
    rest counted; a motor's error meanwhile has its own budget."""
    d = DaemonProcess(tmp_path, CONFIG)
    d.start()
    try:
        bad = bytearray(frame(IsReady(0)))
        bad[-1] ^= 0xFF
        host = Host(str(d.pty))
        try:
            host.write(bytes(bad) * 200 + frame(IsReady(3)) + frame(IsReady(0)))
            answers = host.read(5 * 202)
        finally:
            host.close()
        assert len(answers) == 5 * 202
        errors = d.status()["errors"]
        assert errors["answered"] == 201 and errors["suppressed"] == 201 - BURST
        assert errors["link"]["reason"] == "no motor 3 (this machine has motors 0)"
        log = d.stderr()
        assert log.count("motorctl.errors: link: frame ") == BURST
        assert "motorctl.errors: link: IsReady(motor=3)" not in log  # held back, counted
    finally:
        d.close()


def test_a_missing_port_and_one_that_is_no_serial_device(daemon: DaemonProcess) -> None:
    out = motorctl("-p", "/dev/ttyNOPE", "pos", "0")
    assert out.returncode == 2
    assert out.stderr == (
        "error: cannot open /dev/ttyNOPE: no such file (is motorctld running? its default "
        "port is /run/motorctl/motorctl.pty)\n"
    )
    assert quoted(README, f"`{out.stderr.strip()}`")
    out = motorctl("-p", "/etc/passwd", "pos", "0")
    assert (out.returncode, out.stderr) == (
        2,
        "error: /etc/passwd: not a serial device (a regular file)\n",
    )
    assert quoted(README, f"`{out.stderr.strip()}`")


@pytest.fixture
def root() -> None:
    """Permissions and TIOCEXCL bind every user but root: the CLI runs as user nobody."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.fail("these tests run as root with setpriv (util-linux), as the suite does")
    need_checkout_open_to_others()


def as_nobody(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "motorctl.client.cli", *args]
    return subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *cmd],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd="/",
    )


def test_permission_denied_names_the_group_to_join(root: None) -> None:
    master, slave = os.openpty()
    try:
        device = os.ttyname(slave)
        os.chmod(device, 0o660)  # root's group: not nobody's
        out = as_nobody("-p", device, "pos", "0")
    finally:
        os.close(slave)
        os.close(master)
    assert out.returncode == 2, out.stderr
    assert out.stderr == (
        f"error: cannot open {device}: permission denied: it is not open to this user "
        "(crw-rw----, group root: join the group with 'sudo adduser $USER root' and log in "
        "again)\n"
    )


def test_a_busy_device_says_so(root: None) -> None:
    master, slave = os.openpty()
    try:
        device = os.ttyname(slave)
        os.chmod(device, 0o666)
        fcntl.ioctl(slave, termios.TIOCEXCL)  # held exclusively, as a terminal program does
        out = as_nobody("-p", device, "pos", "0")
    finally:
        os.close(slave)
        os.close(master)
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith(
        f"error: cannot open {device}: busy: another program has it open exclusively"
    )
