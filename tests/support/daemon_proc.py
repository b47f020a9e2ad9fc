"""Run motorctld as a real subprocess on a real PTY, for end-to-end tests.

A daemon (and its step executor process) logs into ``motorctld.stderr`` in its test's
directory, never into pytest's output; when the daemon ends (``close``, ``kill``) its part
of that file is printed to the test's captured stderr, which pytest shows only when the test
fails.
"""

from __future__ import annotations

import os
import select
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Container, Iterator
from pathlib import Path
from typing import Any

from motorctl.client.client import Client, LinkError
from motorctl.daemon.status.reader import StatusReader
from motorctl.protocol.codec import Response
from tests.support import REPO

READY_TIMEOUT_S = 30.0


def run_probe(
    config: Path | str, env: dict[str, str] | None = None, timeout: float = 120.0
) -> subprocess.CompletedProcess[str]:
    """``motorctld --probe --config CONFIG`` as a user runs it, without the platform's
    latency measurement; ``env``: added to this process's environment."""
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--probe",
            "--latency-seconds",
            "0",
            "--config",
            str(config),
        ],
        env={**os.environ, **env} if env is not None else None,
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=timeout,
    )


#: The example config of each world a test daemon's default can be (``MOTORCTL_WORLD``):
#: the embedded default (STEP/DIR motors on the mock), or docs/examples/dspin.toml (the same
#: motors on a chain of mock dSPIN chips; ``make test-dspin`` runs the conformance suite there).
WORLDS = ("default", "dspin")
DSPIN_EXAMPLE = REPO / "docs" / "examples" / "dspin.toml"


def world() -> str:
    """The world a test daemon without a config of its own serves: ``MOTORCTL_WORLD``
    (``default`` when unset); another value is an error, not a fallback."""
    name = os.environ.get("MOTORCTL_WORLD", "default")
    if name not in WORLDS:
        raise ValueError(f"MOTORCTL_WORLD={name!r}: one of {', '.join(WORLDS)}")
    return name


def world_config_text() -> str:
    """The config text of :func:`world`, written out (a test daemon's default)."""
    if world() == "dspin":
        return DSPIN_EXAMPLE.read_text()
    from motorctl.daemon.config import default_config_text

    return default_config_text()


#: The chips :func:`for_world` puts motors on in the dSPIN world, in chain order (the example's)
DSPIN_CHIPS = ("l6470", "l6480", "powerstep01")


def for_world(text: str) -> str:
    """``text`` as a config of :func:`world`: in the dSPIN world each motor without a driver
    chip of its own gets one, on the example's chain (/dev/spidev0.0, 1/16 microsteps, its
    SW input the end stop below the axis); in the default world ``text`` as it is."""
    if world() != "dspin":
        return text
    lines, out, chip = text.splitlines(), [], 0

    def close_motor(body: list[str]) -> None:
        nonlocal chip
        heads = {line.split("#")[0].strip() for line in body}
        if not any(h.startswith(("[motors.dspin]", "[motors.tmc")) for h in heads):
            body += [
                "  [motors.dspin]",
                f'  driver = "{DSPIN_CHIPS[chip % len(DSPIN_CHIPS)]}"',
                '  spi = "/dev/spidev0.0"',
                f"  position = {chip}",
                "  microsteps = 16",
                '  switch = "min"',
            ]
            chip += 1
        out.extend(body)

    motor: list[str] | None = None
    for line in lines:
        head = line.split("#")[0].strip()
        if motor is not None and head.startswith("[") and not head.startswith("[motors."):
            close_motor(motor)
            motor = None
        if head == "[[motors]]":
            motor = [line]
        elif motor is not None:
            motor.append(line)
        else:
            out.append(line)
    if motor is not None:
        close_motor(motor)
    return "\n".join(out) + "\n"


#: The ``motorctld`` fixture (tests/conftest.py): ``start(config_text, **kw)``.
StartDaemon = Callable[..., "DaemonProcess"]


def positions_until_ready(c: Client, motor: int, timeout: float = 10.0) -> list[int]:
    """GetAbsPos of ``motor`` every 50 ms while it moves (until IsReady); fail after
    ``timeout`` seconds. The positions seen on the way, to check the motion was followed."""
    seen = []
    end = time.monotonic() + timeout
    while not c.is_ready(motor):
        seen.append(c.position(motor))
        if time.monotonic() > end:
            raise AssertionError(f"motor {motor} still moving after {timeout} s")
        time.sleep(0.05)
    return seen


def step_thread_from_env(text: str) -> dict[str, str]:
    """``MOTORCTL_TEST_STEP_THREAD``'s [step_thread] keys for every test daemon, as
    ``key=value`` pairs separated by commas (``lead_ms=25``: the emulated lane of make
    test-root, tests/deb/suite-in-root.sh); a pair without ``=`` is an error, not skipped."""
    pairs = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in pairs if "=" not in p or not p.split("=")[0].strip()]
    if bad:
        raise ValueError(f"MOTORCTL_TEST_STEP_THREAD={text!r}: key=value pairs, not {bad}")
    return {k.strip(): v.strip() for k, v in (p.split("=", 1) for p in pairs)}


#: Test daemons run without real-time priority (and lock no memory) on a shared machine.
#: Their lateness rule is the one users get: the mock's simulated motors never lose steps
#: (late steps slide); tests about the fail-safe set ``[mock] lose_steps = true``.
#: ``MOTORCTL_TEST_STEP_THREAD`` adds keys (:func:`step_thread_from_env`).
TEST_STEP_THREAD = {
    "priority": "0",
    "lock_memory": "false",
    **step_thread_from_env(os.environ.get("MOTORCTL_TEST_STEP_THREAD", "")),
}


def for_tests(text: str, force: bool = False) -> str:
    """``text`` with the [step_thread] settings of a test daemon where it does not set them
    (``force``: even where it does, for the embedded default that writes every key out)."""
    lines = text.splitlines()
    try:
        start = next(
            i for i, line in enumerate(lines) if line.split("#")[0].strip() == "[step_thread]"
        )
    except StopIteration:
        extra = "\n".join(f"{k} = {v}" for k, v in TEST_STEP_THREAD.items())
        return f"{text}\n[step_thread]\n{extra}\n"
    end = next(
        (i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines)
    )
    body = lines[start + 1 : end]
    if force:
        body = [line for line in body if line.split("=")[0].strip() not in TEST_STEP_THREAD]
    present = {line.split("=")[0].strip() for line in body if "=" in line}
    add = [f"{k} = {v}" for k, v in TEST_STEP_THREAD.items() if k not in present]
    return "\n".join(lines[: start + 1] + add + body + lines[end:]) + "\n"


class DaemonProcess:
    """motorctld in a process of its own, as the motorctld command starts it. A test daemon
    (the default) gets the test settings (``TEST_STEP_THREAD``) and, without
    ``config_text``, the embedded default written out; ``as_user``: started as a user starts
    it (the benchmarks): ``config_text`` as it is, or none at all (the embedded default).
    A test daemon's default is that of the world ``MOTORCTL_WORLD`` names (:func:`world`),
    and a test daemon's ``config_text`` is made that world's (:func:`for_world`).
    ``command``: what runs before the options (``python -m motorctl.daemon.start.launch``, the
    motorctld command's entry point); ``cwd``: the folder it starts in (the checkout)."""

    def __init__(
        self,
        workdir: Path,
        config_text: str | None = None,
        state_dir: Path | None = None,
        extra: list[str] | None = None,
        env: dict[str, str] | None = None,
        port: str | None = None,
        as_user: bool = False,
        ready_timeout: float = READY_TIMEOUT_S,
        prefix: list[str] | None = None,
        command: list[str] | None = None,
        cwd: Path = REPO,
    ) -> None:
        self.workdir = workdir
        self.command = command or [sys.executable, "-m", "motorctl.daemon.start.launch"]
        self.cwd = cwd
        self.ready_timeout = ready_timeout  # longer in an emulated guest (hwtest/layout.py)
        self.port = port  # serve this serial device (--port) instead of a PTY of its own
        self.pty = workdir / "motorctl.pty"
        self.state_dir = state_dir or workdir / "state"
        self.config: Path | None = workdir / "motorctl.toml"
        if as_user:
            if config_text is None:
                self.config = None
            else:
                self.config.write_text(config_text)
        elif config_text is None:
            self.config.write_text(for_tests(world_config_text(), force=True))
        else:
            self.config.write_text(for_tests(for_world(config_text)))
        self.extra = extra or []
        self.env = env  # added to this process's environment (e.g. NOTIFY_SOCKET)
        self.prefix = prefix or []  # a command that runs motorctld (e.g. prlimit ... --)
        self.proc: subprocess.Popen[bytes] | None = None
        self.ready_line = ""
        self.stderr_path = workdir / "motorctld.stderr"
        self._log_from = 0  # this daemon's part of the file (a restart appends to it)
        self._log_shown = as_user  # a user's daemon: its log is the caller's to read
        # status() reads over one kept connection (tests poll it every millisecond), any
        # thread's reads one at a time; it connects again by itself across restarts
        self._status_reader: StatusReader | None = None
        self._status_lock = threading.Lock()

    def start(self) -> DaemonProcess:
        where = ["--port", self.port] if self.port is not None else ["--pty", str(self.pty)]
        # the motorctld command's entry point (its executor process starts first)
        cmd = [
            *self.prefix,
            *self.command,
            *where,
            "--state-dir",
            str(self.state_dir),
            "--log-level",
            "info",
            *self.extra,
        ]
        if self.config is not None:
            cmd += ["--config", str(self.config)]
        stderr = open(self.stderr_path, "ab")  # noqa: SIM115
        self._log_from = stderr.tell()
        env = {**os.environ, **self.env} if self.env is not None else None
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=stderr, env=env, cwd=self.cwd
        )
        stderr.close()
        assert self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        line = b""
        deadline = time.monotonic() + self.ready_timeout
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(left):
                self.kill()
                raise RuntimeError(f"motorctld not ready: {self.stderr()}")
            chunk = os.read(self.proc.stdout.fileno(), 1)
            if not chunk:
                raise RuntimeError(f"motorctld exited: {self.stderr()}")
            line += chunk
        sel.close()
        self.ready_line = line.decode()
        assert "ready" in self.ready_line, self.ready_line
        return self

    def stderr(self) -> str:
        return self.stderr_path.read_text() if self.stderr_path.exists() else ""

    def client(self, timeout: float = 5.0, **kw: Any) -> Client:
        """A host on the daemon's PTY; a response it does not get says what the daemon
        saw and who else has the PTY open (:class:`DaemonClient`)."""
        return DaemonClient(self, str(self.pty), timeout=timeout, **kw)

    def link_report(self) -> str:
        """What the daemon's link saw (its counters), and every process that has its PTY's
        slave open: what to look at when a host got no answer."""
        parts = []
        try:
            pts = os.readlink(self.pty)
            parts.append(f"{self.pty} -> {pts}, open in: {', '.join(holders(pts)) or 'nobody'}")
        except OSError as exc:
            parts.append(f"{self.pty}: {exc}")
        try:
            counters = self.status()["link"]["counters"]
            parts.append(
                f"link counters: {', '.join(f'{k} {v}' for k, v in counters.items() if v)}"
            )
        except Exception as exc:  # a daemon that does not answer says so
            parts.append(f"no status: {exc!r}")
        return "; ".join(parts)

    def status(self, histogram: bool = False) -> dict[str, Any]:
        """The daemon's status; ``histogram``: with ``steps.histogram_us``. Over one kept
        connection (StatusReader), as a frequent reader should."""
        with self._status_lock:
            if self._status_reader is None:
                self._status_reader = StatusReader(self.state_dir / "status.sock")
            return self._status_reader.read(histogram)

    def _close_status(self) -> None:
        with self._status_lock:
            if self._status_reader is not None:
                self._status_reader.close()
                self._status_reader = None

    def terminate(self, timeout: float = 20.0) -> int:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout)

    def kill(self) -> None:
        self._close_status()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self.show_log()

    def close(self) -> None:
        self._close_status()
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.terminate()
            except subprocess.TimeoutExpired:
                self.kill()
        if self.proc is not None and self.proc.stdout is not None:
            self.proc.stdout.close()
        self.show_log()

    def show_log(self) -> None:
        """This daemon's log, once, to the test's captured stderr (shown if it fails)."""
        if self._log_shown or self.proc is None or not self.stderr_path.exists():
            return
        self._log_shown = True
        with open(self.stderr_path, "rb") as f:
            f.seek(self._log_from)
            text = f.read().decode(errors="replace")
        sys.stderr.write(
            f"---- motorctld (PID {self.proc.pid}) log, {self.stderr_path} "
            f"----\n{text}---- end of the motorctld log ----\n"
        )


class DaemonClient(Client):
    """A :class:`Client` of a :class:`DaemonProcess`: a LinkError (no answer, a short one,
    the port failed) adds :meth:`DaemonProcess.link_report`."""

    def __init__(self, daemon: DaemonProcess, port: str, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.daemon = daemon

    def read_response(self, timeout: float | None = None) -> Response:
        try:
            return super().read_response(timeout)
        except LinkError as exc:
            raise LinkError(f"{exc} [{self.daemon.link_report()}]") from exc


def processes() -> Iterator[Path]:
    """Every process's folder in /proc (one may be gone by the time it is read)."""
    return (entry for entry in Path("/proc").iterdir() if entry.name.isdigit())


def has_open(process: Path, paths: Container[str]) -> bool:
    """Whether ``process`` (its /proc folder) holds a descriptor of one of ``paths``;
    OSError when it is gone or not ours to read."""
    return any(os.readlink(fd) in paths for fd in (process / "fd").iterdir())


def holders(path: str) -> list[str]:
    """Every process with ``path`` open, as "PID (its command line)" (this one's too)."""
    out = []
    for entry in processes():
        try:
            if has_open(entry, (path,)):
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                out.append(f"{entry.name} ({cmd.strip()[:120]})")
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return out


def children_of(pid: int) -> list[int]:
    """The PIDs whose parent is ``pid`` (zombies included)."""
    out = []
    for entry in processes():
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.append(int(entry.name))
    return sorted(out)


def memfd_labels(pid: int) -> set[str]:
    """The labels of the memfd blocks (``/memfd:LABEL``) process ``pid`` maps."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {
        line.split("/memfd:", 1)[1].split(" (deleted)")[0]
        for line in maps.splitlines()
        if "/memfd:" in line
    }


def memfd_holders(labels: set[str]) -> list[int]:
    """Every process on the machine that still maps, or holds a descriptor of, a memfd
    labelled one of ``labels`` (a memfd lives exactly as long as one of those)."""
    wanted = {f"/memfd:{label} (deleted)" for label in labels}
    holders = []
    for entry in processes():
        try:
            held = any(
                line.split(None, 5)[-1] in wanted
                for line in (entry / "maps").read_text().splitlines()
                if "/memfd:" in line
            ) or has_open(entry, wanted)
        except OSError:  # gone meanwhile, or not ours to read
            continue
        if held:
            holders.append(int(entry.name))
    return holders


def without_real_time() -> list[str]:
    """A command prefix under which the kernel refuses motorctld real time, for real:
    RLIMIT_RTPRIO 0 and RLIMIT_MEMLOCK 64 KiB (prlimit), and, for root, no CAP_SYS_NICE
    nor CAP_IPC_LOCK, which would override them (setpriv drops them from the bounding set
    before the exec: root keeps every other capability). What a user without the unit's
    LimitRTPRIO and LimitMEMLOCK gets."""
    prefix = ["prlimit", "--rtprio=0", f"--memlock={64 * 1024}", "--"]
    if os.geteuid() == 0:
        prefix += ["setpriv", "--bounding-set=-sys_nice,-ipc_lock", "--"]
    return prefix


def run_on_pty(cmd: list[str], timeout: float = 30.0) -> tuple[int, str]:
    """``cmd`` with a real pseudo-terminal as its stdin, stdout and stderr (as a person runs
    it in a terminal): its exit status and everything it wrote."""
    master, slave = os.openpty()
    try:
        proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, cwd=REPO)
    finally:
        os.close(slave)
    out = b""
    deadline = time.monotonic() + timeout
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                proc.kill()
                raise AssertionError(f"{cmd} still writing after {timeout} s: {out!r}")
            ready, _, _ = select.select([master], [], [], left)
            if not ready:
                continue
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: every end of the terminal's other side is closed
                break
            if not chunk:
                break
            out += chunk
        return proc.wait(timeout), out.decode().replace("\r\n", "\n")
    finally:
        os.close(master)
