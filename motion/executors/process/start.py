"""Starting the step executor's process (``child.py``); light to import.

That process takes longer to start than anything else in motorctld's start-up: a second
Python interpreter, then the step core's modules. So ``motorctld`` (``daemon/start/launch.py``)
starts it first thing, before the daemon's own imports, and both interpreters start side by
side; the daemon hands it its parameters once it has read its config and made the shared
memory (:class:`~motorctl.motion.executors.process.parent.ProcessStepExecutor`). This
module imports nothing of motorctl (its packages' ``__init__`` modules hold docstrings
only), so the early start costs no import of its own.

The process runs ``python -I -c`` :data:`BOOTSTRAP` with one end of a Unix
``SOCK_SEQPACKET`` socket pair as its stdin. Isolated (``-I``): neither the current folder
(which ``-c`` alone puts first on the import path: a module ``pickle`` in the folder ``sudo
motorctld`` was started from would run as root) nor a script's folder is ever on its path,
nor anything ``PYTHON*`` variables or the user's site add. The first message is the
daemon's PID (the child dies with it), the daemon's import path without the entries that
name where it was started (:func:`import_path`) and where the daemon's ``motorctl`` package
is: the child imports that very package, whatever its path holds. It then names itself
for ``ps`` (:func:`name_process`), imports the step core (no automatic garbage collection
from the first line on: ``child.py`` collects once while it waits, then runs without it;
with the compiled code of its dataclasses' methods that the package's build recorded, as
the daemon: ``motorctl/dataclass_code.py``) and waits for the second: its
parameters, pickled, with its descriptors (``SCM_RIGHTS``: the shared block, its pipe ends,
the step IO's). The end of the socket without a message (the daemon did not need it, or is
gone) ends it quietly.

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

#: What ``ps`` shows as the child's command line (``ps -f``, ``ps aux``, ``pgrep -a``)...
TITLE = "motorctld: step executor"
#: ... and as its name (``ps -e``, ``top``, ``pgrep``; the kernel keeps 15 bytes of it).
COMM = "motorctld-step"

#: The child's program, run isolated (``-I``). SIGINT, SIGTERM and SIGHUP are the daemon's
#: to act on (a service manager signals the whole control group, a terminal the whole
#: process group): ignored from the start, the daemon ends the child once it has stopped the
#: motors. The import path becomes the daemon's (without where it was started, see
#: :func:`import_path`) before this interpreter's own, and ``motorctl`` the daemon's package.
BOOTSTRAP = """\
# motorctld step executor
import gc
gc.disable()  # child.py collects and freezes while it waits, then runs without it
import pickle, signal, socket, sys
for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
    signal.signal(s, signal.SIG_IGN)
channel = socket.socket(fileno=0)
first = channel.recv(1 << 20)
if not first:
    sys.exit()  # the daemon is gone already
daemon, path, (init, folders) = pickle.loads(first)
sys.path[:] = path + [p for p in sys.path if p not in path]
import importlib.util
spec = importlib.util.spec_from_file_location("motorctl", init, submodule_search_locations=folders)
sys.modules["motorctl"] = package = importlib.util.module_from_spec(spec)
spec.loader.exec_module(package)
from motorctl.motion.executors.process.start import name_process
title_note = name_process()
from motorctl.dataclass_code import CodeCache
codes = CodeCache.load()  # the build's compiled dataclass methods (the daemon logs a problem)
with codes.use():
    from motorctl.motion.executors.process.child import child_main
child_main(channel, daemon, title_note, codes)
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
            proc = subprocess.Popen([sys.executable, "-I", "-c", BOOTSTRAP], stdin=theirs.fileno())
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        with contextlib.suppress(OSError):  # it died at once: the hand-over says so
            ours.send(pickle.dumps((os.getpid(), import_path(), package_location())))
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


def import_path() -> list[str]:
    """The daemon's import path for the executor: :func:`isolated_path` of ``sys.path``."""
    try:
        cwd = os.getcwd()
    except OSError:  # removed since: nothing can be found there by a relative name either
        cwd = None
    return isolated_path(sys.path, cwd, sys.argv[0] if sys.argv else "")


def isolated_path(path: Sequence[str], cwd: str | None, script: str) -> list[str]:
    """``path`` without what names the folder a process was started from or in: every
    relative entry (``''``, ``.``, ``lib``: looked up in the current folder), the current
    folder ``cwd`` by any absolute name, and the folder of ``script`` (``sys.argv[0]``: a
    script's own folder, the console script's ``/usr/bin`` included, when it is a file).
    What stays is where the daemon's modules and libraries come from: the standard
    library, site-packages, ``PYTHONPATH``'s absolute entries."""
    unsafe = set()
    if cwd is not None:
        unsafe.add(os.path.realpath(cwd))
    if script and os.path.isfile(script):
        unsafe.add(os.path.dirname(os.path.realpath(script)))
        unsafe.add(os.path.dirname(os.path.abspath(script)))
    return [p for p in path if os.path.isabs(p) and os.path.realpath(p) not in unsafe]


def package_location() -> tuple[str, list[str]]:
    """Where the daemon's ``motorctl`` package is: its ``__init__`` file and its folders."""
    package = sys.modules["motorctl"]  # this module's own package: imported already
    if package.__file__ is None:
        raise RuntimeError("the motorctl package has no __init__ file")
    return package.__file__, list(package.__path__)


def name_process(title: str = TITLE, comm: str = COMM) -> str:
    """Name this process for ``ps``: ``comm`` as its name (``prctl(PR_SET_NAME)``), and
    ``title`` as its command line, written over the interpreter's own arguments in the
    process's memory (where ``/proc/PID/cmdline`` reads them: the kernel keeps their place
    in ``/proc/self/stat``), padded with NUL bytes, only if that place holds exactly
    ``sys.orig_argv`` and ``title`` fits (the interpreter has its own copy of them). The
    empty string when both were done, else what could not be, and why."""
    import ctypes

    problems = []
    libc = ctypes.CDLL(None, use_errno=True)  # the interpreter's own libc (no ldconfig run)
    if libc.prctl(15, comm.encode()[:15], 0, 0, 0) != 0:  # PR_SET_NAME
        problems.append(f"name: prctl(PR_SET_NAME): {os.strerror(ctypes.get_errno())}")
    new = title.encode()
    try:
        with open("/proc/self/stat", "rb") as f:
            # after the name (in parentheses, any bytes): fields 3 on; arg_start is 48
            fields = f.read().rsplit(b")", 1)[1].split()
        if len(fields) < 47:  # qemu-user's own /proc/self/stat ends before arg_start
            raise ValueError(f"/proc/self/stat has {len(fields) + 2} fields, no arg_start")
        start, end = int(fields[45]), int(fields[46])
        with open("/proc/self/mem", "r+b", buffering=0) as mem:
            mem.seek(start)
            old = mem.read(end - start)
            if old != b"\0".join(os.fsencode(a) for a in sys.orig_argv) + b"\0":
                problems.append("command line: its memory does not hold the arguments")
            elif len(new) >= len(old):
                problems.append(f"command line: {len(old)} bytes, too few for the title")
            else:
                mem.seek(start)
                mem.write(new + bytes(len(old) - len(new)))
    except (OSError, IndexError, ValueError) as exc:
        problems.append(f"command line: {exc}")
    return "; ".join(problems)


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
