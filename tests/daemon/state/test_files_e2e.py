"""Issue 22 end to end: motorctld started as users start it (the ``motorctld`` command), as
root, with its state directory, its PTY and its trace file in a shared sticky folder (like
/tmp) where another user placed traps at every path it writes (tests/support/traps.py);
a state file the JSON parser cannot take; a config that is a FIFO, a folder, or starts
with a UTF-8 byte order mark. Nothing is followed, opened or written through, nothing
hangs, nothing crashes: the daemon starts, serves and stops cleanly. Every kind of trap at
every path, in-process: tests/daemon/state/test_files.py."""

from __future__ import annotations

import codecs
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess
from tests.support.traps import KINDS, VICTIM_TEXT, Trap, place, shared_folder

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

#: What the daemon writes in its state directory and beside its PTY (besides state.json).
WRITTEN = (
    "motorctld.lock",
    ".motorctl.pty.lock",
    "state.json.tmp",
    "state.moving",
    "status.sock",
    "trace.pcapng",
)
#: What state.json holds at each start: what Python's parser refused with a traceback at
#: every start (issue 22), and a file over the bound (sparse: cheap to make, long to read).
POISON = {
    "nested 200,000 deep": b"[" * 200_000,
    "an integer of 5,000 digits": b'{"version": 2, "motors": [], "n": ' + b"9" * 5000 + b"}",
    "100 MB": None,
}


@pytest.mark.parametrize("start", range(3), ids=list(POISON))
def test_a_start_among_traps_at_every_path(tmp_path: Path, start: int) -> None:
    """Three starts, each with a different kind of trap at each path (every kind in two of
    them), the PTY path a link to the other user's file, a poisoned state file and a
    config with a byte order mark."""
    shared = shared_folder(tmp_path)
    traps = [
        place(shared / name, KINDS[(2 * start + j) % len(KINDS)]) for j, name in enumerate(WRITTEN)
    ]
    state = shared / "state.json"
    poison = list(POISON.values())[start]
    if poison is None:
        with open(state, "wb") as f:
            f.truncate(100 << 20)
    else:
        state.write_bytes(poison)
    pty = place(shared / "motorctl.pty", "link")
    d = DaemonProcess(shared, state_dir=shared, extra=["--trace", str(shared / "trace.pcapng")])
    assert d.config is not None
    d.config.write_bytes(codecs.BOM_UTF8 + d.config.read_bytes())
    try:
        d.start()
        with d.client() as c:
            assert c.position(0) == 0
        doc = d.status()
        assert doc["state"]["ok"] is True
        assert doc["state"]["restored"].startswith("nothing restored")
        log = d.stderr()
        for trap in traps:
            stale_socket = trap.path.name == "status.sock" and trap.kind == "socket"
            trap.check(set_aside=not stale_socket)
            lines = [
                line
                for line in log.splitlines()
                if f"{trap.path} was " in line or f"{trap.path} is " in line
            ]
            assert len(lines) == (0 if stale_socket else 1), (trap, lines)
        assert f"{state}" in log and f"kept it as {state}.bad" in log
        assert os.readlink(pty.path) != str(pty.victim)  # replaced, never followed
        assert pty.victim.read_bytes() == VICTIM_TEXT
        trace = os.lstat(shared / "trace.pcapng")
        assert stat.S_ISREG(trace.st_mode) and trace.st_uid == os.geteuid()
        assert stat.S_IMODE(trace.st_mode) & 0o007 == 0  # 0640 less the umask
        assert d.terminate() == 0
    finally:
        d.close()
    assert "Traceback" not in d.stderr(), d.stderr()
    for trap in traps:  # its own files removed at exit; what it set aside kept
        assert trap.victim.read_bytes() == VICTIM_TEXT
    for name in ("motorctld.lock", ".motorctl.pty.lock", "status.sock"):
        assert not os.path.lexists(shared / name)


def _motorctld(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    """motorctld as a user (or ExecStartPre=) runs it; a hang fails by the timeout."""
    return subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.launch", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=timeout,
    )


def _fifo_or_folder(path: Path, kind: str) -> Trap | None:
    if kind == "fifo":
        return place(path, "fifo")
    path.mkdir()
    return None


@pytest.mark.parametrize("kind", ["fifo", "directory"])
def test_a_config_that_is_not_a_file_is_refused_at_once(tmp_path: Path, kind: str) -> None:
    """Issue 22: a FIFO as --config hung --check-config (ExecStartPre=) and the daemon
    for ever."""
    shared = shared_folder(tmp_path)
    config = shared / "motorctl.toml"
    trap = _fifo_or_folder(config, kind)
    what = {"fifo": "a FIFO", "directory": "a directory"}[kind]
    message = f"error: {config}: is {what}, not a regular file; fix: give the path of a TOML file"
    check = _motorctld("--check-config", str(config))
    assert (check.returncode, check.stderr.strip()) == (1, message)
    serve = _motorctld(
        "--config", str(config), "--pty", str(shared / "x"), "--state-dir", str(shared / "s")
    )
    assert serve.returncode == 1 and message in serve.stderr, serve.stderr
    assert "Traceback" not in serve.stderr
    assert not os.path.lexists(shared / "s")  # refused before anything was made
    if trap is not None:
        trap.check(set_aside=False)


def test_a_config_with_a_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    config = tmp_path / "motorctl.toml"
    config.write_bytes(codecs.BOM_UTF8 + b'[[motors]]\nname = "x"\n')
    check = _motorctld("--check-config", str(config))
    assert check.returncode == 0, check.stderr
    assert check.stdout.startswith(f"{config}: OK (1 motors")
    config.write_bytes(codecs.BOM_UTF8 + b'[[motors]]\nname = "x"\nmax_speed = "fast"\n')
    check = _motorctld("--check-config", str(config))
    assert check.returncode == 1
    assert check.stderr.startswith(f"error: {config}: motors[0].max_speed = ")


@pytest.mark.parametrize("kind", [k for k in KINDS if "link" not in k and k != "device"])
def test_what_stands_at_the_pty_path_is_set_aside(tmp_path: Path, kind: str) -> None:
    """The PTY path (daemon/link/ports.py): a link there is replaced, never followed (above);
    anything else but a device is set aside with one line, never opened or waited for,
    and the daemon serves."""
    shared = shared_folder(tmp_path)
    trap = place(shared / "motorctl.pty", kind)
    d = DaemonProcess(shared, state_dir=shared / "s")
    try:
        d.start()
        with d.client() as c:
            assert c.position(0) == 0
        lines = [line for line in d.stderr().splitlines() if f"{trap.path} was " in line]
        assert len(lines) == 1, lines
        trap.check(set_aside=True)
        assert os.path.islink(trap.path)
        assert d.terminate() == 0
    finally:
        d.close()
    assert "Traceback" not in d.stderr(), d.stderr()


def test_a_device_at_the_pty_path_is_refused_and_left_alone(tmp_path: Path) -> None:
    """``--pty /dev/ttyS0`` is a mistake: a device node is never opened, nor renamed (as
    root that would break a system); the start stops with a clear error."""
    shared = shared_folder(tmp_path)
    trap = place(shared / "x", "device")
    serve = _motorctld("--pty", str(trap.path), "--state-dir", str(shared / "s"))
    assert serve.returncode == 1, serve.stderr
    assert f"error: {trap.path} is a character device: --pty names the link" in serve.stderr
    assert "Traceback" not in serve.stderr
    trap.check(set_aside=False)
    assert os.lstat(trap.path).st_ino == trap.identity[1]
