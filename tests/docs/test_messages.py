"""Every message README.md and docs/*.md quote is what the code prints: each is produced by
running what makes it, and the page's quote is compared with the output.

``QUOTES`` lists each quote with the run that produces it (``RUNS``, by name): a command on
a config snippet (``motorctld --check-config``, its entry point called as the console script
calls it, with the snippet at the path the page shows), ``motorctld --probe``, a daemon
that refuses to start, and one daemon session on a serial device that is missing at start,
appears, goes away and comes back (its log, the notifications it sends systemd, its status
socket's answers, a second daemon's refusal, its stop by SIGHUP). A quote is a pattern:
``...`` leaves text out and its ``wild`` words stand for the run's values (quotes.py).

So when a message changes, its test fails until the page says what the code prints, wherever
the message comes from; the README's client walkthrough is run by test_readme.py instead.
Every message-like quote on the pages (``quotes.candidates``) must be in ``QUOTES``, so a new
one cannot go unchecked. Not here: Python's and other programs' own messages
(``ModuleNotFoundError`` in a build log, lintian), and output listings that are not messages.

Two come from the GPIO character device, which only the hardware tier has: the busy line's
message is made by the function the backend raises it with (hwtest/test_daemon.py starts a
daemon against a held line), and the compiled core's journal line on GPIO character devices
is asserted by hwtest/test_daemon.py as quoted (the ``tier`` run reads those assertions).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import resource
import selectors
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from motorctl.client import reasons
from motorctl.client.cli import main as cli
from motorctl.daemon.config import parse_config
from motorctl.daemon.start import launch
from motorctl.daemon.start.assemble import motor_identities
from motorctl.hal.backends.gpiod.chip import busy_message
from motorctl.hal.backends.gpiod.wiring import LineRef, ResolvedLine
from motorctl.protocol.capture.format import CaptureInfo
from motorctl.protocol.codec import ErrorCode, MoveTo, WaitMoved
from tests.docs.quotes import PAGES, Quote, candidates, on_page, rel, squash
from tests.support import REPO, traces
from tests.support.daemon_proc import run_probe
from tests.support.frames import frame
from tests.support.fsutil import read_only
from tests.support.stand_ins import stand_in_env
from tests.support.wait import until

ETC = "/etc/motorctl.toml"
MOTOR = '[[motors]]\nname = "x"\n'

#: config snippets, each with the message the page shows for it (docs/config.md's paths)
SNIPPETS = {
    "max_speed 0": MOTOR + '[[motors]]\nname = "y"\nmax_speed = 0\n',
    "held_frames true": "[link]\nheld_frames = true\n" + MOTOR,
    "frame_gap": "[link]\nframe_gap = 5\n" + MOTOR,
    "soft limit alone": MOTOR + "soft_limit_min = -500\n",
    "a wire to no pin": MOTOR
    + '[[pins]]\nnumber = 0\n[[pins]]\nnumber = 1\nmode = "input"\n'
    + "[mock]\nwires = [[0, 1], [1, 2]]\n",
    "backend gpio": '[hal]\nbackend = "gpio"\n' + MOTOR,
    "no motors": "[link]\n",
    "TOML syntax": MOTOR + "max_speed =@\n",
    "default above max": MOTOR + "max_speed = 1000\n",
    "y without STEP": '[hal]\nbackend = "gpiod"\n'
    + MOTOR
    + '[motors.gpiod]\nstep = "GPIO17"\ndir = "GPIO27"\n'
    + '[[motors]]\nname = "y"\n[motors.gpiod]\ndir = "GPIO23"\n',
    "driver_poll_ms": "[step_thread]\ndriver_poll_ms = 10.0\n" + MOTOR,
}

#: a motor with a TMC2130 where a TMC5160 answers (tests/fakespi/ stands in for py-spidev)
TMC2130 = MOTOR + '[motors.tmc]\ndriver = "tmc2130"\nspi = "/dev/spidev0.0"\n'
CONFIG_MD = "docs/config.md"
QUOTES = [
    *(
        Quote(CONFIG_MD, text, f"check: {name}")
        for name, text in [
            (
                "max_speed 0",
                f"{ETC}: motors[1].max_speed = 0: out of range; accepted: a number > 0 and "
                "<= 200000",
            ),
            (
                "held_frames true",
                f"{ETC}: link.held_frames = true: wrong type (boolean); accepted: an integer "
                "in 1..1024",
            ),
            (
                "frame_gap",
                f"{ETC}: unknown key 'link.frame_gap'; accepted keys in [link]: checksum, "
                "crc_covers_ack, frame_gap_ms, held_frames, strict_padding",
            ),
            (
                "soft limit alone",
                f"{ETC}: motors[0].soft_limit_min = -500: soft_limit_max is not set; accepted: "
                "set both soft_limit_min and soft_limit_max, or neither",
            ),
            (
                "a wire to no pin",
                f"{ETC}: mock.wires[1] = [1, 2]: pin 2 is not in [[pins]] (configured pins: "
                "0, 1); accepted: every wired pin is listed in [[pins]]",
            ),
            (
                "backend gpio",
                f'{ETC}: hal.backend = "gpio": unknown value; accepted: one of "mock", '
                '"gpiod" (the backends of motorctl.hal.registry)',
            ),
            (
                "no motors",
                f"{ETC}: motors: missing; accepted: 1..64 [[motors]] tables (a config needs "
                "at least one)",
            ),
            (
                "TOML syntax",
                f"{ETC}: line 3: TOML syntax error: Invalid value (at line 3, column 12)",
            ),
            (
                "driver_poll_ms",
                f"warning: {ETC}: 'step_thread.driver_poll_ms' is retired and ignored: the "
                "HAL's one driver poller reads every driver chip now and hands a fault to the "
                "motors as it reads it, with nothing to do with the step thread; its period is "
                "[drivers] poll_ms; fix: remove it",
            ),
            (
                "default above max",
                f"{ETC}: motors[0].default_speed = 2000.0: out of range (the default value; "
                "set the key explicitly); accepted: a number > 0 and <= max_speed "
                "(max_speed = 1000)",
            ),
        ]
    ),
    Quote(
        CONFIG_MD,
        f"{ETC}: config file not found; fix: create it (`motorctld --print-default-config` "
        "prints a commented example; docs/config.md describes every key) or give the path of "
        "an existing file",
        "check: no file",
    ),
    Quote(
        CONFIG_MD,
        f"{ETC}: is a FIFO, not a regular file; fix: give the path of a TOML file",
        "check: a FIFO",
    ),
    Quote(
        "README.md",
        "error: my.toml: motors[1].max_speed = 0: out of range; accepted: a number > 0 and "
        "<= 200000",
        "readme: my.toml",
    ),
    Quote(
        "docs/raspberry-pi.md",
        "/etc/motorctl/motorctl.toml: OK (3 motors, 8 pins, a DC motor, backend gpiod)",
        "check: the example",
    ),
    Quote(
        "docs/tmc.md",
        "motors[1].gpiod.step: missing: motor 1 ('y') is moved by STEP/DIR pulses and needs "
        "its STEP line ...",
        "check: y without STEP",
    ),
    Quote(
        "docs/tmc.md",
        'configured as TMC2130 ... but found a TMC5160; set driver = "tmc5160" or check '
        "which chip select this driver is wired to",
        "start: another chip",
    ),
    Quote("docs/hardware.md", "PROBLEM: ...", "probe: another chip"),
    Quote(
        "docs/hardware.md",
        "motors[2].step: line gpiochip0:5 'GPIO5' is already in use by 'intruder'; stop that "
        "program (see `gpioinfo`), or remove the device-tree overlay ...",
        "gpiod: a busy line",
    ),
    Quote(
        "docs/timing.md",
        'error: the step executor cannot start: [step_thread] core = "compiled", but ...',
        "start: no compiled core",
    ),
    Quote("docs/timing.md", "...; step core compiled; ...", "served"),
    Quote("docs/timing.md", "step core: compiled (its lines: GPIO character devices)", "tier"),
    # one daemon on a serial device: docs/protocol.md, docs/service.md, docs/status.md
    Quote("docs/protocol.md", "serial device PATH is gone (...)", "served", ("PATH",)),
    Quote(
        "docs/protocol.md",
        "serial device PATH is back after 0.1 s (2 attempts): serving again",
        "served",
        ("PATH", "0.1", "2"),
    ),
    Quote(
        "docs/protocol.md",
        "STATUS=... WAITING FOR SERIAL DEVICE PATH (not there yet)",
        "served",
        ("PATH",),
    ),
    Quote(
        "docs/protocol.md",
        "serial device PATH is not there: serving it as soon as it appears",
        "served",
        ("PATH",),
    ),
    Quote(
        "docs/protocol.md",
        "serial device PATH is there after 30.2 s (...): serving it",
        "served",
        ("PATH", "30.2"),
    ),
    Quote("docs/protocol.md", "link timeout: no byte from the host for N ms", "served", ("N",)),
    Quote("docs/service.md", "SCHED_FIFO ... not permitted", "served"),
    Quote(
        "docs/service.md",
        "error: --pty /nonexistent/dir/x.pty: the folder /nonexistent/dir does not exist; create"
        " it ('mkdir -p /nonexistent/dir') or give --pty a path in an existing folder",
        "start: --pty in a missing folder",
    ),
    Quote("README.md", "error: E2 invalid address: no motor 5", "client: errors"),
    Quote(
        "README.md",
        "error: cannot open /dev/ttyNOPE: no such file (is motorctld running? its default port"
        " is /run/motorctl/motorctl.pty)",
        "client: errors",
    ),
    Quote(
        "README.md", "error: /etc/passwd: not a serial device (a regular file)", "client: errors"
    ),
    Quote(
        "docs/service.md",
        "3 motors: 1 moving, none faulted; 1234 frames served, 0 errors",
        "served",
        ("1", "1234", "0"),
    ),
    Quote(
        "docs/service.md",
        "SERIAL DEVICE PATH GONE, reopening it when it is back",
        "served",
        ("PATH",),
    ),
    Quote("docs/service.md", "WAITING FOR SERIAL DEVICE PATH (not there yet)", "served", ("PATH",)),
    Quote(
        "docs/service.md",
        "STATUS=...; WAITING FOR SERIAL DEVICE /dev/serial/by-id/usb-... (not there yet)",
        "served",
    ),
    Quote(
        "docs/service.md",
        "serial device PATH is not there: serving it as soon as it appears",
        "served",
        ("PATH",),
    ),
    Quote(
        "docs/service.md",
        "serial device PATH is there after 30.2 s (...): serving it",
        "served",
        ("PATH", "30.2"),
    ),
    Quote(
        "docs/service.md",
        "another motorctld (PID 1234) already serves the state directory ...",
        "served",
        ("1234",),
    ),
    Quote(
        "docs/service.md",
        "... was a FIFO, in the way of a file of this daemon: moved aside to ....bad",
        "served",
    ),
    Quote("docs/service.md", "... has motor 'q', which the config does not have", "served"),
    Quote(
        "docs/service.md",
        "stopped WITHOUT saving the final state (cannot write state file ...)",
        "served",
    ),
    Quote(
        "docs/service.md",
        "SIGHUP (the terminal closed, or someone asked): stopping as for SIGTERM",
        "served",
    ),
    Quote(
        "docs/service.md",
        "... is a character device: --pty names the link the daemon makes to its own PTY; "
        "choose another path",
        "start: --pty on a device",
    ),
    Quote(
        "docs/status.md",
        '{"error": "unknown status request: ...; known: histogram, subscribe [PERIOD_MS], keep"}',
        "served",
    ),
    Quote(
        "docs/status.md",
        '{"error": "too many subscribers (8), each reading its updates: the daemon is full; ..."}',
        "served",
    ),
    Quote("docs/status.md", "not sent: its host's session ended", "served"),
    Quote("docs/raspberry-pi.md", "3 motors: 0 moving, none faulted; ...", "served"),
    # motorctl trace and replay on made-up and damaged recordings: docs/trace.md
    *(
        Quote("docs/trace.md", text, "trace files", wild)
        for text, wild in [
            ("warning: FILE: ...", ("FILE",)),
            (
                "the file holds interfaces 0: host /dev/pts/5 <-> device ... (tap, 34 runs), 1: "
                "/run/motorctl/motorctl.pty -> /dev/pts/3 (daemon, 34 runs): each decoded as "
                "its own link",
                ("34",),
            ),
            (
                "session 3f2a9c01d4e5 (parts 3..5) lacks part 4: the frames recorded there are "
                "not here, and frames and answers around the hole may pair wrongly",
                ("3f2a9c01d4e5", "3..5", "4"),
            ),
            (
                "the start of session 3f2a9c01d4e5 (part 1) is missing: the first part given is "
                "part 3; ...",
                ("3f2a9c01d4e5", "3"),
            ),
            ("a pcap file of link type 1 (Ethernet)", ()),
            ("the file ends inside a block at offset 1234 (...)", ("1234",)),
            (
                "damaged at offset 1234: ...; the 620 bytes from there on cannot be read",
                ("1234", "620"),
            ),
            ("nothing to replay", ()),
        ]
    ),
    Quote("docs/raspberry-pi.md", "3 motors: 0 moving, ...", "served"),
]


# --- the runs ---------------------------------------------------------------------------------


def check_config(path: Path, capsys: pytest.CaptureFixture[str], cwd: Path | None = None) -> str:
    """``motorctld --check-config PATH`` through the entry point the console script calls:
    what it printed and its exit status."""
    here = Path.cwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        status = launch.main(["--check-config", str(path)])
    finally:
        os.chdir(here)
    out = capsys.readouterr()
    return f"{out.out}{out.err}exit status {status}\n"


def check_snippet(name: str) -> Callable[[Path, pytest.CaptureFixture[str]], str]:
    def run(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
        path = tmp / "motorctl.toml"
        path.write_text(SNIPPETS[name], encoding="utf-8")
        return check_config(path, capsys).replace(str(path), ETC)

    return run


def check_missing(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    return check_config(tmp / "motorctl.toml", capsys).replace(str(tmp / "motorctl.toml"), ETC)


def check_fifo(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    os.mkfifo(tmp / "motorctl.toml")
    return check_missing(tmp, capsys)


def check_readme(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """The README's ``motorctld --check-config my.toml``, in the folder of my.toml."""
    (tmp / "my.toml").write_text(SNIPPETS["max_speed 0"], encoding="utf-8")
    return check_config(Path("my.toml"), capsys, cwd=tmp)


def check_example(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """The example copied to where raspberry-pi.md section 6 copies it."""
    path = tmp / "motorctl.toml"
    shutil.copy(REPO / "docs" / "examples" / "raspberry-pi.toml", path)
    return check_config(path, capsys).replace(str(path), "/etc/motorctl/motorctl.toml")


def probe_another_chip(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """``motorctld --probe`` where a TMC5160 answers for a driver configured as TMC2130
    (tests/fakespi/ stands in for py-spidev)."""
    config = tmp / "motorctl.toml"
    config.write_text(TMC2130, encoding="utf-8")
    out = run_probe(config, env=stand_in_env("spidev", chips={"0.0": "tmc5160"}))
    return out.stdout + out.stderr


def gpiod_busy_line(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """The message the gpiod backend raises for a line another program holds, for z's STEP
    of the example on a Pi 4 (hwtest/test_daemon.py has a daemon meet it on gpio-sim)."""
    line = ResolvedLine("motors[2].step", LineRef.parse("GPIO5"), "/dev/gpiochip0", 5, "", "GPIO5")
    return busy_message(line, "intruder")


def tier_assertions(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """What the hardware tier's tests assert the daemon printed: their string literals."""
    literal = re.compile(r'"((?:[^"\\\n]|\\.)*)"')
    files = sorted((REPO / "hwtest").glob("test_*.py"))
    return "\n".join(m for p in files for m in literal.findall(p.read_text(encoding="utf-8")))


def start_refused(
    extra: list[str], config: str, env: dict[str, str] | None = None
) -> Callable[[Path, pytest.CaptureFixture[str]], str]:
    """A daemon start that must fail (exit 1): what it printed. ``{tmp}`` in ``extra``:
    the test's folder."""

    def run(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
        path = tmp / "motorctl.toml"
        path.write_text(config, encoding="utf-8")
        cmd = [sys.executable, "-m", "motorctl.daemon.start.launch"]
        cmd += [arg.format(tmp=tmp) for arg in extra]
        cmd += ["--state-dir", str(tmp / "state"), "--config", str(path)]
        out = subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            timeout=120,
            cwd=REPO,
            env={**os.environ, **(env or {})},
        )
        assert out.returncode == 1, out.stdout + out.stderr
        return out.stdout + out.stderr

    return run


TEST_THREAD = "[step_thread]\npriority = 0\nlock_memory = false\n"


# --- one daemon on a serial device ---------------------------------------------------------

#: the port's name in the output: the udev name docs/service.md shows
PORT_NAME = "/dev/serial/by-id/usb-FTDI_A1B2C3-if00-port0"
SERVED_CONFIG = """\
[link]
timeout_ms = 1000
[step_thread]
priority = 1
lock_memory = false
[[motors]]
name = "x"
[[motors]]
name = "y"
[[motors]]
name = "z"
"""


def state_with_q() -> str:
    """The state file a daemon of this config wrote, plus the record of a motor "q" its
    config no longer has (docs/service.md): x, y, z are restored (their positions known),
    q is named in a warning."""
    config = parse_config(SERVED_CONFIG, "served.toml")
    records = [
        {
            "name": name,
            "fingerprint": fingerprint,
            "position": 0,
            "home": 0,
            "waypoints": [],
            "moving": False,
            "position_lost": False,
        }
        for name, fingerprint in [
            *((i.name, i.fingerprint) for i in motor_identities(config)),
            ("q", "-"),
        ]
    ]
    return json.dumps({"version": 2, "motors": records})


READY_TIMEOUT_S = 60.0


class Session:
    """motorctld serving ``--port`` at a path where the test makes and removes PTYs, with
    systemd's notification socket, without the capability to raise its own priority."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.port = tmp / "tty"
        self.state = tmp / "state"
        self.log = tmp / "motorctld.stderr"
        self.notes: list[str] = []
        self.said: list[str] = []  # what the test read from the daemon's sockets and others
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify.bind(str(tmp / "notify"))
        self.notify.setblocking(False)
        self.master = -1
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.state.mkdir()
        os.mkfifo(self.state / "motorctld.lock")  # in the way of the daemon's lock file
        (self.state / "state.json").write_text(state_with_q(), encoding="utf-8")
        config = self.tmp / "motorctl.toml"
        config.write_text(SERVED_CONFIG, encoding="utf-8")
        # SCHED_FIFO refused, as on a machine whose limits do not allow it
        wrap = ["setpriv", "--bounding-set", "-sys_nice"] if os.geteuid() == 0 else []
        cmd = [
            *wrap,
            sys.executable,
            "-m",
            "motorctl.daemon.start.launch",
            "--port",
            str(self.port),
        ]
        cmd += ["--state-dir", str(self.state), "--config", str(config), "--log-level", "info"]
        env = {**os.environ, "NOTIFY_SOCKET": str(self.tmp / "notify")}
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                cmd,
                stdout=subprocess.PIPE,
                stderr=log,
                env=env,
                cwd=REPO,
                preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0)),
            )
        self.said.append(self._ready_line())

    def _ready_line(self) -> str:
        assert self.proc is not None and self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        line = b""
        end = time.monotonic() + READY_TIMEOUT_S
        while not line.endswith(b"\n"):
            if not sel.select(max(0.0, end - time.monotonic())):
                raise AssertionError(f"motorctld not ready: {self.text()}")
            chunk = os.read(self.proc.stdout.fileno(), 1)
            assert chunk, f"motorctld exited: {self.text()}"
            line += chunk
        sel.close()
        return line.decode()

    def text(self) -> str:
        while True:
            try:
                self.notes.append(self.notify.recv(4096).decode())
            except BlockingIOError:
                break
        return self.log.read_text(errors="replace") + "\n".join(self.notes + self.said)

    def wait_for(self, what: str) -> None:
        until(repr(what), lambda: what in self.text(), detail=self.text, every_s=0.02)

    def plug(self) -> None:
        """A new PTY at the port's path (a device that appears)."""
        self.master, slave = os.openpty()
        link = self.tmp / "tty.new"
        link.symlink_to(os.ttyname(slave))
        os.close(slave)
        os.replace(link, self.port)

    def unplug(self) -> None:
        """The device goes, and its name with it (udev removes a USB adapter's node and its
        by-id link): the link first, then the PTY. A link left to a /dev/pts/N that is gone
        names the next PTY made with that number, anyone's: the daemon, opening its port's
        path again every so often, took another test's daemon's PTY for its device and read
        that daemon's answers before its host could (its first GetAbsPos unanswered)."""
        self.port.unlink()
        os.close(self.master)
        self.master = -1

    def send(self, data: bytes, answers: int) -> bytes:
        os.write(self.master, data)
        got = b""
        end = time.monotonic() + 30.0
        while len(got) < 5 * answers:
            sel = selectors.DefaultSelector()
            sel.register(self.master, selectors.EVENT_READ)
            ready = sel.select(max(0.0, end - time.monotonic()))
            sel.close()
            assert ready, f"no answer: {self.text()}"
            got += os.read(self.master, 64)
        return got

    def ask(self, request: bytes) -> str:
        """One request on the status socket, answered until the server closes."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(self.state / "status.sock"))
            s.settimeout(30.0)
            s.sendall(request)
            return read_all(s)

    def close(self) -> None:
        if self.master >= 0:
            self.unplug()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(30)
        self.notify.close()


def read_all(s: socket.socket) -> str:
    chunks = []
    while chunk := s.recv(65536):
        chunks.append(chunk)
    return b"".join(chunks).decode()


def first_line(s: socket.socket) -> str:
    data = b""
    while not data.endswith(b"\n"):
        chunk = s.recv(65536)
        assert chunk, "the status socket closed"
        data += chunk
    return data.decode()


@contextlib.contextmanager
def subscribers(path: Path, n: int) -> Iterator[list[socket.socket]]:
    """``n`` subscribers of the status socket, each having read its first update."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            socks.append(s)
            s.connect(str(path))
            s.settimeout(30.0)
            s.sendall(b"subscribe\n")
            first_line(s)
        yield socks
    finally:
        for s in socks:
            s.close()


def served(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """The session (see ``Session``): a device missing at start, then there; a move, the
    host silent past ``[link] timeout_ms``; a WaitMoved held when the device goes away, and
    the device back; the status socket asked something unknown and a ninth subscriber; a
    second daemon on the same state directory; SIGHUP with the state directory read-only."""
    s = Session(tmp)
    try:
        s.start()
        s.wait_for("is not there: serving it as soon as it appears")
        s.plug()
        s.wait_for("EVENT=device_appeared")
        s.send(frame(MoveTo(0, True, 1_000_000, 200, 0, 0)), 1)
        s.wait_for(" 1 moving")
        s.wait_for("link timeout: no byte from the host")
        s.send(frame(MoveTo(1, True, 1_000_000, 200, 0, 0)), 1)
        os.write(s.master, frame(WaitMoved(1, 60_000)))  # held until y stops: never
        until("the WaitMoved held", lambda: json.loads(s.ask(b"\n"))["link"]["waiting"])
        s.unplug()
        s.wait_for("GONE, reopening it when it is back")
        s.said.append(s.ask(b"\n"))  # the status document: the WaitMoved's answer dropped
        s.plug()
        s.wait_for("EVENT=device_back")
        s.said.append(s.ask(b"bogus\n"))
        with subscribers(s.state / "status.sock", 8), socket.socket(socket.AF_UNIX) as ninth:
            ninth.connect(str(s.state / "status.sock"))
            ninth.settimeout(30.0)
            ninth.sendall(b"subscribe\n")
            s.said.append(read_all(ninth))
        second = subprocess.run(
            [
                *(
                    sys.executable,
                    "-m",
                    "motorctl.daemon.start.launch",
                    "--pty",
                    str(tmp / "other.pty"),
                ),
                *("--state-dir", str(s.state), "--config", str(tmp / "motorctl.toml")),
            ],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=REPO,
        )
        assert second.returncode == 1, second.stderr
        s.said.append(second.stderr)
        assert s.proc is not None
        with read_only(s.state):
            s.proc.send_signal(signal.SIGHUP)
            assert s.proc.wait(60) == 4, s.text()
        return s.text().replace(str(s.port), PORT_NAME)
    finally:
        s.close()


def client_errors(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """``motorctl`` (the CLI's entry point) on a port that does not exist and on a file that
    is no serial device, and an error answer explained where no daemon's status socket is
    found: the code's meaning for that command (client/reasons.py, as the CLI calls it)."""
    out = []
    for argv in [["-p", "/dev/ttyNOPE", "pos", "0"], ["-p", "/etc/passwd", "pos", "0"]]:
        status = cli(argv)
        said = capsys.readouterr()
        out.append(f"$ motorctl {' '.join(argv)}\n{said.err}exit status {status}\n")
    nowhere = {reasons.STATE_DIR_ENV: str(tmp / "no-state")}
    line = reasons.explain(
        ErrorCode.INVALID_ADDRESS, MoveTo(5, True, 0, 0, 0, 0), "", 0.0, env=nowhere
    )
    out.append(f"error: {line}\n")
    return "".join(out)


def trace_files(tmp: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """``motorctl trace`` and ``motorctl replay`` (the CLI's entry point) on recordings
    made as tests/support/traces.py makes them: rotated parts with a hole and without
    their start, a file cut mid-block, a block of an impossible length, a pcap file of
    Ethernet, a header and nothing else, a tap's and a daemon's recording merged."""
    _, path = traces.rotating(tmp, 3)
    parts = [path.with_name(f"{path.name}.{n}") for n in (2, 1)] + [path]
    data = path.read_bytes()
    blocks = traces.block_offsets(data)
    cut = tmp / "cut.pcapng"
    cut.write_bytes(data[: blocks[3] + 6])
    damaged = bytearray(data)
    struct.pack_into("<I", damaged, blocks[3] + 4, 3)  # a block length no block has
    (tmp / "damaged.pcapng").write_bytes(bytes(damaged))
    (tmp / "ether.pcap").write_bytes(traces.pcap(traces.conversation(), linktype=1))
    (tmp / "empty.pcapng").write_bytes(data[: blocks[2]])
    tap = CaptureInfo(role="tap", port="host /dev/pts/5 <-> device /dev/ttyUSB0")
    daemon = CaptureInfo(role="daemon", port="/run/motorctl/motorctl.pty -> /dev/pts/3")
    both = traces.merged((tap, traces.conversation()), (daemon, traces.conversation()))
    (tmp / "merged.pcapng").write_bytes(both)
    out = []
    for argv in [
        ["trace", str(parts[0]), str(path)],
        ["trace", *map(str, parts)],
        ["trace", str(cut)],
        ["trace", str(tmp / "damaged.pcapng")],
        ["trace", str(tmp / "ether.pcap")],
        ["replay", str(tmp / "empty.pcapng"), "--port", "/nonexistent"],
        ["trace", str(tmp / "merged.pcapng")],
    ]:
        status = cli(argv)
        said = capsys.readouterr()
        out.append(f"$ motorctl {' '.join(argv)}\n{said.err}exit status {status}\n")
    return "".join(out)


RUNS: dict[str, Callable[[Path, pytest.CaptureFixture[str]], str]] = {
    "trace files": trace_files,
    "client: errors": client_errors,
    "start: --pty in a missing folder": start_refused(["--pty", "/nonexistent/dir/x.pty"], MOTOR),
    **{f"check: {name}": check_snippet(name) for name in SNIPPETS},
    "check: no file": check_missing,
    "check: a FIFO": check_fifo,
    "check: the example": check_example,
    "readme: my.toml": check_readme,
    "probe: another chip": probe_another_chip,
    "gpiod: a busy line": gpiod_busy_line,
    "tier": tier_assertions,
    "start: no compiled core": start_refused(
        ["--pty", "{tmp}/motorctl.pty"],
        MOTOR + '[step_thread]\ncore = "compiled"\npriority = 0\nlock_memory = false\n',
        {"MOTORCTL_STEPCORE": "/nonexistent/_stepcore.so"},
    ),
    "start: --pty on a device": start_refused(["--pty", "/dev/null"], MOTOR + TEST_THREAD),
    "start: another chip": start_refused(
        ["--pty", "{tmp}/motorctl.pty"],
        TMC2130 + TEST_THREAD,
        stand_in_env("spidev", chips={"0.0": "tmc5160"}),
    ),
    "served": served,
}


# --- the tests --------------------------------------------------------------------------------


def _id(quote: Quote) -> str:
    return f"{quote.page}: {quote.text[:60]}"


@pytest.mark.parametrize("quote", QUOTES, ids=_id)
def test_each_quote_is_on_its_page(quote: Quote) -> None:
    assert quote.run in RUNS, quote.run
    assert on_page(quote), f"{quote.page} no longer quotes {quote.text!r}: update QUOTES"


@pytest.mark.parametrize("page", PAGES, ids=rel)
def test_every_quoted_message_is_checked(page: Path) -> None:
    listed = [q for q in QUOTES if q.page == rel(page)]
    unchecked = [
        c
        for c in candidates(page.read_text(encoding="utf-8"))
        if not any(squash(c) in squash(q.text) or squash(q.text) in squash(c) for q in listed)
    ]
    assert not unchecked, f"{rel(page)} quotes messages no test produces: {unchecked}"


@pytest.mark.parametrize("run", sorted(RUNS), ids=str)
def test_what_the_pages_quote_is_what_the_code_prints(
    run: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    output = RUNS[run](tmp_path, capsys)
    assert run == "tier" or "Traceback" not in output, output
    wrong = [q for q in QUOTES if q.run == run and not q.found_in(output)]
    assert not wrong, (
        "these quotes are not what the code prints; make the page say what it prints:\n"
        + "\n".join(f"  {q.page}: {q.text}" for q in wrong)
        + f"\n---- what {run!r} printed ----\n{output}"
    )


def test_an_unplugged_device_leaves_no_name_for_the_next_pty(tmp_path: Path) -> None:
    """``Session.unplug`` removes the port's link with the PTY (see there): nothing at the
    port's path names the /dev/pts/N that the next PTY, anyone's, gets."""
    s = Session(tmp_path)
    try:
        s.plug()
        pts = os.readlink(s.port)
        s.unplug()
        assert not os.path.lexists(s.port), f"{s.port} -> {pts} left behind"
    finally:
        s.close()
