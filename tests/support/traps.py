"""Traps at the paths the daemon writes, placed as another user of a shared folder would.

:func:`shared_folder` makes a folder like /tmp (mode 1777, root's). :func:`place` puts a
``kind`` of thing at a path there, owned by another user (``OTHER``, nobody): a symbolic link
to that user's file (the *victim*), a dangling link (whose *target* must never be made), a
FIFO, a directory, a hard link to the victim, a plain file of that user, a character device
(/dev/null's numbers: harmless if it were opened) or a socket file. :meth:`Trap.check`
says afterwards that nothing was written through, created or opened, and that the thing
was set aside under ``NAME.bad`` as it was.

A FIFO gets a rescue: should anything open it and wait (the bug the traps look for), its
other end is opened once after ``RESCUE_S`` so that the test fails instead of hanging.

Only root can place another user's files (the traps' point): :func:`need_root` skips
otherwise.
"""

from __future__ import annotations

import contextlib
import os
import socket
import stat
import threading
from dataclasses import dataclass, field
from pathlib import Path

import pytest

OTHER = 65534  # nobody
KINDS = (
    "link",
    "dangling link",
    "fifo",
    "directory",
    "hard link",
    "their file",
    "device",
    "socket",
)
RESCUE_S = 10.0
VICTIM_TEXT = b"the other user's precious file\n"


def need_root() -> None:
    if os.geteuid() != 0:
        pytest.skip("placing another user's files in a shared folder needs root")


def shared_folder(parent: Path, name: str = "shared") -> Path:
    """A folder anyone may write, sticky, root's: like /tmp."""
    need_root()
    folder = parent / name
    folder.mkdir()
    os.chmod(folder, 0o1777)
    return folder


@dataclass
class Trap:
    path: Path
    kind: str
    victim: Path
    target: Path  # what a dangling link names
    identity: tuple[int, int] = (0, 0)
    rescue: threading.Timer | None = field(default=None, repr=False)

    def check(self, set_aside: bool = True) -> None:
        """Nothing written through, nothing created at a link's target, nothing left
        waiting on a FIFO; ``set_aside``: the very thing stands at ``NAME.bad`` now."""
        if self.rescue is not None:
            self.rescue.cancel()
        assert self.victim.read_bytes() == VICTIM_TEXT, f"{self.kind} at {self.path}: written"
        assert not os.path.lexists(self.target), f"{self.kind} at {self.path}: target made"
        if set_aside:
            bad = self.path.with_name(self.path.name + ".bad")
            st = os.lstat(bad)
            assert (st.st_dev, st.st_ino) == self.identity, f"{bad} is not the {self.kind}"
            assert st.st_uid == OTHER


def place(path: Path, kind: str) -> Trap:
    """Put a ``kind`` of thing (one of ``KINDS``) at ``path``, owned by ``OTHER``."""
    folder = path.parent
    victim = folder / f"victim-of-{path.name}"
    victim.write_bytes(VICTIM_TEXT)
    os.chown(victim, OTHER, OTHER)
    target = folder / f"made-through-{path.name}"
    trap = Trap(path, kind, victim, target)
    if kind == "link":
        path.symlink_to(victim)
    elif kind == "dangling link":
        path.symlink_to(target)
    elif kind == "fifo":
        os.mkfifo(path, 0o666)
        trap.rescue = threading.Timer(RESCUE_S, _unblock_fifo, [path])
        trap.rescue.daemon = True
        trap.rescue.start()
    elif kind == "directory":
        path.mkdir()
        (path / "inside").write_text("theirs")
    elif kind == "hard link":
        os.link(victim, path)
    elif kind == "their file":
        path.write_text("theirs\n")
    elif kind == "device":
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    elif kind == "socket":
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.bind(str(path))
    else:
        raise AssertionError(kind)
    os.chown(path, OTHER, OTHER, follow_symlinks=False)
    st = os.lstat(path)
    trap.identity = (st.st_dev, st.st_ino)
    return trap


def _unblock_fifo(path: Path) -> None:
    """Open the FIFO's other ends once (wherever it was moved: ``.bad`` too): whoever is
    stuck opening it goes on, and the test fails instead of hanging."""
    for where in (path, path.with_name(path.name + ".bad")):
        with contextlib.suppress(OSError):
            os.close(os.open(where, os.O_RDONLY | os.O_NONBLOCK))
        with contextlib.suppress(OSError):  # ENXIO: nobody reads it
            os.close(os.open(where, os.O_WRONLY | os.O_NONBLOCK))
