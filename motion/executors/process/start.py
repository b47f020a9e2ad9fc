"""Starting the step executor's process (``child.py``); light to import.

That process takes longer to start than anything else in motorctld's start-up: a second
Python interpreter, then the step core's modules. So ``motorctld`` (``daemon/launch.py``)
starts it first thing, before the daemon's own imports, and both interpreters start side by
side; the daemon hands it its parameters once it has read its config and made the shared
memory (:class:`~motorctl.motion.executors.process.parent.ProcessStepExecutor`). This
module imports nothing of motorctl (its packages' ``__init__`` modules hold docstrings
only), so the early start costs no import of its own.

The process runs ``python -c`` :data:`BOOTSTRAP` with one end of a Unix ``SOCK_SEQPACKET``
socket pair as its stdin. The first message is the daemon's PID (the child dies with it)
and ``sys.path`` (so that both processes import the very same modules); the child then
imports the step core and waits for
the second: its parameters, pickled, with its descriptors (``SCM_RIGHTS``: the shared block,
its pipe ends, the step IO's). The end of the socket without a message (the daemon did not
need it, or is gone) ends it quietly.

Owners: the daemon's main thread (start, hand over, dismiss).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import socket
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported where a process is started: the executor's own needs none
    import subprocess

#: The child's program (its first line is what ``ps`` shows after ``python -c``). SIGINT,
#: SIGTERM and SIGHUP are the daemon's to act on (a service manager signals the whole
#: control group, a terminal the whole process group): ignored from the start, the daemon
#: ends the child once it has stopped the motors.
BOOTSTRAP = """\
# motorctld step executor
import pickle, signal, socket, sys
for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
    signal.signal(s, signal.SIG_IGN)
channel = socket.socket(fileno=0)
first = channel.recv(1 << 20)
if not first:
    sys.exit()  # the daemon is gone already
daemon, sys.path[:] = pickle.loads(first)
from motorctl.motion.executors.process.child import child_main
child_main(channel, daemon)
"""

#: The largest parameter message and the most descriptors it may carry.
MAX_MESSAGE = 1 << 20
MAX_FDS = 16


class WaitingInterpreter:
    """The step executor's interpreter, started and waiting for its parameters."""

    def __init__(self, proc: subprocess.Popen[bytes], channel: socket.socket) -> None:
        self.proc = proc
        self._channel: socket.socket | None = channel

    @classmethod
    def start(cls) -> WaitingInterpreter:
        """Start the interpreter; OSError when it cannot be (``sys.executable`` missing)."""
        import subprocess

        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            proc = subprocess.Popen([sys.executable, "-c", BOOTSTRAP], stdin=theirs.fileno())
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        with contextlib.suppress(OSError):  # it died at once: the hand-over says so
            ours.send(pickle.dumps((os.getpid(), list(sys.path))))
        return cls(proc, ours)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def waiting(self) -> bool:
        """Not handed over nor dismissed yet."""
        return self._channel is not None

    def hand_over(self, params: dict[str, Any], fds: Sequence[int]) -> None:
        """Send the parameters and (copies of) ``fds``; the caller may close its own then.
        OSError when the process is gone; ValueError when the message is too big."""
        channel = self._channel
        if channel is None:
            raise RuntimeError("the executor process was handed over or dismissed already")
        message = pickle.dumps(params)
        if len(message) > MAX_MESSAGE or len(fds) > MAX_FDS:
            raise ValueError(
                f"executor parameters of {len(message)} bytes with {len(fds)} "
                f"descriptors: at most {MAX_MESSAGE} and {MAX_FDS}"
            )
        self._channel = None
        try:
            socket.send_fds(channel, [message], list(fds))
        finally:
            channel.close()

    def dismiss(self) -> None:
        """Not needed after all (or the start failed): end it now. Nothing if it was handed
        over (its owner ends it)."""
        if self._channel is None:
            return
        self._channel.close()
        self._channel = None
        self.proc.kill()
        self.proc.wait()


def receive(channel: socket.socket) -> tuple[dict[str, Any], list[int]] | None:
    """The child's side: the parameters and the descriptors, or None when the daemon ended
    the socket without them (dismissed, or gone)."""
    try:
        message, fds, flags, _ = socket.recv_fds(channel, MAX_MESSAGE, MAX_FDS)
    finally:
        channel.close()
    if not message:
        for fd in fds:
            os.close(fd)
        return None
    if flags & (socket.MSG_TRUNC | socket.MSG_CTRUNC):
        raise ValueError("the executor's parameters arrived cut short")
    params = pickle.loads(message)
    if not isinstance(params, dict):
        raise TypeError(f"the executor's parameters are a {type(params).__name__}")
    return params, fds
