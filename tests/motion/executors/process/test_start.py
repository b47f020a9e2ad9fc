"""Starting the executor process (motion/executors/process/start.py): light to import (the
daemon's launch imports it before anything else of motorctl), the parameters and their
descriptors handed over once over the socket, a message too big refused before anything
goes, an interpreter not needed after all ended and reaped, and the child's side of the
socket. (The daemon's early start: tests/daemon/start/test_launch.py.)"""

from __future__ import annotations

import os
import pickle
import socket
import subprocess
import sys

import pytest

from motorctl.motion.executors.process.start import MAX_FDS, WaitingInterpreter, receive
from tests.support import REPO


def test_importing_it_loads_nothing_of_motorctl_but_its_own_packages() -> None:
    """Only the packages on its way, whose ``__init__`` modules hold docstrings only."""
    code = (
        "import sys; import motorctl.motion.executors.process.start; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'motorctl'))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[0] == str(
        [
            "motorctl",
            "motorctl.motion",
            "motorctl.motion.executors",
            "motorctl.motion.executors.process",
            "motorctl.motion.executors.process.start",
        ]
    )


def pair() -> tuple[socket.socket, socket.socket]:
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)


def test_the_child_receives_the_parameters_and_their_descriptors() -> None:
    ours, theirs = pair()
    r, w = os.pipe()
    try:
        socket.send_fds(ours, [pickle.dumps({"motors": 2})], [w])
        got = receive(theirs)
        assert got is not None
        params, fds = got
        assert params == {"motors": 2} and len(fds) == 1
        os.write(fds[0], b"x")  # a descriptor of the same pipe
        assert os.read(r, 1) == b"x"
        os.close(fds[0])
    finally:
        ours.close()
        for fd in (r, w):
            os.close(fd)


def test_a_socket_ended_without_parameters_is_none_and_parameters_not_a_table_refused() -> None:
    ours, theirs = pair()
    ours.close()
    assert receive(theirs) is None  # dismissed, or the daemon is gone
    ours, theirs = pair()
    ours.send(pickle.dumps([1, 2]))
    ours.close()
    with pytest.raises(TypeError, match="parameters are a list"):
        receive(theirs)


def test_a_message_too_big_is_refused_before_anything_goes() -> None:
    early = WaitingInterpreter.start()
    try:
        assert early.waiting and early.pid == early.proc.pid
        with pytest.raises(ValueError, match=f"at most .* and {MAX_FDS}"):
            early.hand_over({}, [0] * (MAX_FDS + 1))
        assert early.waiting  # nothing went: the caller may still dismiss it
    finally:
        early.dismiss()
    with pytest.raises(RuntimeError, match="handed over or dismissed already"):
        early.hand_over({}, [])


def test_an_interpreter_not_needed_is_ended_and_reaped() -> None:
    early = WaitingInterpreter.start()
    early.dismiss()
    assert not early.waiting and early.proc.returncode is not None
    early.dismiss()  # twice: nothing


def test_a_short_proc_stat_is_said_not_indexed(monkeypatch: pytest.MonkeyPatch) -> None:
    """qemu-user (the arm64 lane) answers /proc/self/stat itself, with fewer fields than the
    kernel's: the note says so, and nothing of the process's memory is touched."""
    import builtins
    import io

    from motorctl.motion.executors.process import start

    real_open = builtins.open

    def short_stat(path: object, *args: object, **kw: object) -> object:
        if path == "/proc/self/stat":
            return io.BytesIO(b"42 (python3) S " + b"0 " * 40)
        if path == "/proc/self/mem":
            raise AssertionError("the memory was opened")
        return real_open(path, *args, **kw)  # type: ignore[call-overload]

    with real_open("/proc/self/comm") as f:
        comm = f.read().strip()  # this process keeps its name
    monkeypatch.setattr(start, "open", short_stat, raising=False)
    note = start.name_process("motorctld: step executor", comm)
    assert note == "command line: /proc/self/stat has 43 fields, no arg_start", note
