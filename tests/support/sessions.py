"""The link's pure parts in front of a daemon on a virtual clock (``SessionRig``): the
session (daemon/link/session.py) and the silence watch the config asks for
(daemon/link/silence.py), driven as the link's loop drives them, without a PTY: bytes and
times in, answers out. The dispatcher, the engine and the thread step executor behind them
are the real ones, so "the motor is moving" is the engine's own state, not a script.
"""

from __future__ import annotations

from pathlib import Path

from motorctl.daemon.link.session import LinkSession
from motorctl.daemon.start.link_parts import silence_watch
from motorctl.hal.interfaces import VirtualClock
from motorctl.protocol.codec import Command, GetAbsPos, Response
from tests.support.frames import OPTS, answers, frame
from tests.support.inprocess import build_daemon

#: the frame gap of the rig's session
GAP_S = 0.010
#: how finely :meth:`SessionRig.quiet` lets time pass (the loop's turns)
STEP_S = 0.005


class SessionRig:
    """A daemon of config ``text`` on a virtual clock with a session in front of it
    (``held`` frames behind a WaitMoved, ``backlog`` answers owed at most) and the silence
    watch of its ``[link]`` table."""

    def __init__(self, tmp: Path, text: str, held: int = 16, backlog: int = 4096) -> None:
        self.clock = VirtualClock()
        self.daemon = build_daemon(text, tmp, self.clock)
        self.engine = self.daemon.engine
        self.motors = self.engine.motors
        self.session = LinkSession(self.daemon.dispatcher, OPTS, GAP_S, held, backlog)
        self.watch = silence_watch(self.daemon.config, self.daemon.dispatcher, self.clock.now())

    @property
    def now(self) -> float:
        return self.clock.now()

    # -- the host's bytes ---------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes from the host now (the watch hears them, the session takes them)."""
        now = self.now
        self.watch.heard(now)
        self.session.receive(data, now)

    def send(self, *cmds: Command) -> None:
        """``cmds``' frames in one read, now."""
        self.receive(frame(*cmds))

    def responses(self) -> list[Response]:
        """The answers the session has for the host."""
        return answers(self.session.take_output())

    def ask(self, data: bytes) -> list[Response]:
        """Bytes from the host now; the answers they got at once."""
        self.receive(data)
        return self.responses()

    def call(self, cmd: Command) -> Response:
        (resp,) = self.ask(frame(cmd))
        return resp

    # -- time passing -------------------------------------------------------------------
    def run(self, dt: float) -> None:
        """Let the motors move for ``dt`` seconds, then let the session look at its wait."""
        self.engine.run_until(self.now + dt)
        self.session.poll(self.now)

    def quiet(self, seconds: float) -> list[Response]:
        """Let ``seconds`` pass with no byte from the host, in the loop's turns (the
        session's watched silence, the watch's hold and check); the answers that came."""
        end = self.now + seconds
        out = bytearray()
        while self.now < end - 1e-9:
            t = min(end, self.now + STEP_S)
            self.engine.run_until(t)
            if self.session.waiting:
                self.session.poll(t)
            self.session.idle(STEP_S)
            self.watch.hold(self.session.waiting, t)
            self.watch.check(t)
            out += self.session.take_output()
        return answers(out)

    def poll_host(self, seconds: float, every_s: float = 0.1) -> None:
        """Let ``seconds`` pass with the host asking GetAbsPos(0) every ``every_s``."""
        end = self.now + seconds
        while self.now < end - 1e-9:
            self.quiet(min(every_s, end - self.now))
            self.call(GetAbsPos(0))

    def quiet_until_answered(self, limit_s: float = 10.0) -> list[Response]:
        """Let time pass with no byte from the host until an answer comes (at most
        ``limit_s``); the answers."""
        end = self.now + limit_s
        while self.now < end:
            got = self.quiet(STEP_S)
            if got:
                return got
        raise AssertionError(f"no answer within {limit_s} s")

    def timeouts(self) -> int:
        """How often the host's silence stopped the motors."""
        return self.watch.counters["link_timeouts"]
