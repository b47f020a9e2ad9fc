"""Daemons built in the test's own process (``Daemon.build``), and a live one serving a
real PTY: its link loop on a thread, the host's side opened as a host program opens a
serial port.

``LiveDaemon`` runs on a virtual clock by default (the tests are about the bytes); with
``motion=True`` it runs on the real clock with the step executor's and the engine's threads
started, as the daemon does (the tests are about what the motors do).
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from pathlib import Path
from typing import Any

from motorctl.daemon.config import parse_config
from motorctl.daemon.link.loop import Link
from motorctl.daemon.link.ports import PtySlave, open_pty
from motorctl.daemon.start.assemble import Daemon
from motorctl.hal.backends.mock.world import MockWorld, world_of
from motorctl.hal.interfaces import Clock, MonotonicClock, VirtualClock
from motorctl.protocol.codec import Command, ErrorCode, GetAbsPos, Move, Response
from tests.support.daemon_proc import TEST_STEP_THREAD
from tests.support.frames import OPTS, answers, frame
from tests.support.wait import WAIT_S, until

#: Two motors "a" and "b" with every other setting at its default.
TWO_MOTORS = '[[motors]]\nname = "a"\n[[motors]]\nname = "b"\n'

#: The config of an in-process daemon whose motors run on the real clock: the thread step
#: executor, the best-effort timing of a test daemon, two motors "a" and "b"; tests append
#: their own tables.
IN_PROCESS_CONFIG = (
    '[step_thread]\nexecutor = "thread"\n'
    + "".join(f"{k} = {v}\n" for k, v in TEST_STEP_THREAD.items())
    + TWO_MOTORS
)

#: ``IN_PROCESS_CONFIG`` with output pin 0: a live daemon with motors and a pin.
LIVE_CONFIG = IN_PROCESS_CONFIG + '[[pins]]\nnumber = 0\nmode = "output"\n'


def build_daemon(text: str, state_dir: Path, clock: Clock | None = None) -> Daemon:
    """The daemon of config ``text`` (a virtual clock unless given), not serving."""
    return Daemon.build(parse_config(text, "test.toml"), state_dir, clock or VirtualClock())


class Host:
    """The other side of the PTY, opened like a serial port by a host program."""

    def __init__(self, path: str) -> None:
        # non-blocking: a write never waits inside the kernel for room the daemon may never
        # make (it stopped reading), so that ``stop`` always ends one within 50 ms
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def write(self, data: bytes, stop: threading.Event | None = None) -> None:
        """Write it all (waiting for room, as a host does), or until ``stop`` is set."""
        view = memoryview(data)
        end = time.monotonic() + 120.0
        while view and not (stop is not None and stop.is_set()):
            assert time.monotonic() < end, "the daemon never took the host's bytes"
            if select.select([], [self.fd], [], 0.05)[1]:
                with contextlib.suppress(BlockingIOError):
                    view = view[os.write(self.fd, view[:4096]) :]

    def read(self, n: int, timeout: float = WAIT_S) -> bytes:
        out = bytearray()
        end = time.monotonic() + timeout
        while len(out) < n:
            left = end - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                break
            with contextlib.suppress(BlockingIOError):
                out += os.read(self.fd, n - len(out))
        return bytes(out)

    def responses(self, n: int, timeout: float = WAIT_S) -> list[Response]:
        data = self.read(5 * n, timeout)
        assert len(data) == 5 * n, f"got {len(data) // 5} of {n} responses in {timeout} s"
        return answers(data)

    def nothing_within(self, seconds: float) -> bool:
        return not select.select([self.fd], [], [], seconds)[0]

    def close(self) -> None:
        os.close(self.fd)


class LiveDaemon:
    """An in-process daemon whose Link serves a real PTY (or ``fd``) on a thread.

    ``port``: what the link hands commands to instead of the daemon's dispatcher;
    ``start``: False to start the link thread yourself; the other keywords go to ``Link``.
    """

    def __init__(
        self,
        tmp: Path,
        config: str = TWO_MOTORS,
        *,
        motion: bool = False,
        port: Any = None,
        fd: int | None = None,
        gap_s: float = 0.010,
        start: bool = True,
        slave_watch: bool = True,
        **link_kw: Any,
    ) -> None:
        clock = MonotonicClock() if motion else VirtualClock()
        self.daemon = build_daemon(config, tmp / "state", clock)
        self.world: MockWorld = world_of(self.daemon.hw)
        self.motion = motion
        self.path = tmp / "pty"
        if fd is None:
            fd, self.name = open_pty(self.path)
            link_kw.setdefault("pty", PtySlave(fd, self.name, watch=slave_watch))
        self.fd = fd
        self.link = Link(fd, port or self.daemon.dispatcher, OPTS, gap_s, 16, **link_kw)
        self.daemon.link = self.link
        self.thread = threading.Thread(target=self.link.serve, name="link", daemon=True)
        self._host: Host | None = None
        if motion:
            self.daemon.engine.executor.start()
            self.daemon.engine.start()
        if start:
            self.thread.start()

    def host(self) -> Host:
        """A new host on the PTY (the caller closes it)."""
        return Host(self.name)

    def ask(self, *cmds: Command) -> list[Response]:
        """Send ``cmds`` in one write from this daemon's own host; their answers."""
        if self._host is None:
            self._host = self.host()
        self._host.write(frame(*cmds))
        return self._host.responses(len(cmds))

    def code(self, cmd: Command) -> ErrorCode | None:
        return self.ask(cmd)[0].error_code

    def moving(self, motor: int) -> None:
        """Start ``motor`` running forwards; return once it has moved (``motion`` only)."""
        assert self.code(Move(motor, True, 1, 0, 0)) is None
        until(f"motor {motor} moving", lambda: self.ask(GetAbsPos(motor))[0].as_position > 0)

    def counters(self) -> dict[str, Any]:
        counters = self.link.status()["counters"]
        assert isinstance(counters, dict)
        return counters

    def until(self, what: str, cond: Any, timeout: float = WAIT_S) -> None:
        """``until`` that names the link's counters when it fails."""
        until(what, cond, timeout, detail=self.counters, every_s=0.005)

    def alive(self) -> bool:
        """The link thread and, with ``motion``, the engine's and the executor's threads."""
        engine = self.daemon.engine
        motors = not self.motion or (engine.threads_alive and engine.executor.health().alive)
        return motors and self.thread.is_alive()

    def stop(self, timeout: float = WAIT_S) -> float:
        """Stop the link loop; how long it took."""
        t = time.monotonic()
        self.link.stop()
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "the link thread did not stop"
        return time.monotonic() - t

    def close(self) -> None:
        if self._host is not None:
            self._host.close()
        if self.thread.is_alive():
            self.stop()
        if self.motion:
            self.daemon.engine.stop_threads()
            self.daemon.engine.executor.close()
        self.link.close()
        os.close(self.fd)
