"""A step executor that stalls, and the dispatcher over it: ``SlowToConfirm`` wraps a real
executor and holds back its stop confirmations (``delay_s``; None: until ``release``) and
dies on cue, while the motor really stops; ``stall_rig`` builds the engine and the
dispatcher of a config over it, on the clock given (a virtual one: time passes when the
test says; the real one: start the executor's and the engine's threads). The hard
StopMove's tests (tests/daemon/test_dispatcher_hardstop.py) are its users.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from motorctl.daemon.config import Config, parse_config
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.start.assemble import build_executor, hardware_spec, motor_params
from motorctl.hal.interfaces import Clock, Hardware, VirtualClock
from motorctl.hal.registry import open_hardware
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import (
    STOP_CONFIRM_S,
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
    ExecutorHealth,
    from_ticks,
    to_ticks,
)
from motorctl.motion.profile import Trajectory
from motorctl.motion.types import Ramp
from motorctl.protocol.codec import (
    Command,
    GetAbsPos,
    IsReady,
    Response,
)
from tests.support.inprocess import IN_PROCESS_CONFIG


class SlowToConfirm(Executor):
    """``inner`` with its stop confirmations held back ``delay_s`` (None: until
    :meth:`release`), and a death on cue (:meth:`die`, or at ``dies_at`` on a virtual
    clock)."""

    def __init__(self, inner: Executor, clock: Clock, delay_s: float | None = None) -> None:
        super().__init__(inner.motors)
        self.inner = inner
        self.clock = clock
        self.delay_s = delay_s
        self.dies_at: float | None = None
        self.dead = False
        self._died_reported = False
        self._asked: dict[tuple[int, int], float] = {}  # (motor, gen) -> confirm from
        self._held: list[tuple[float, ExecEvent]] = []
        self._lock = threading.Lock()
        inner.on_event = self._forward

    def _forward(self) -> None:
        self.on_event()

    def release(self) -> None:
        """The stalled executor runs again: every confirmation held so far comes."""
        with self._lock:
            self._held = [(float("-inf"), ev) for _, ev in self._held]
            self._asked = dict.fromkeys(self._asked, float("-inf"))
        self.on_event()

    def die(self) -> None:
        self.dead = True
        self.on_event()

    # -- the seam ----------------------------------------------------------------------
    def stop(self, motor: int, gen: int) -> int | None:
        # on the step path's ticks, as a real executor's times are (a virtual clock stops there)
        due = (
            float("inf")
            if self.delay_s is None
            else from_ticks(to_ticks(self.clock.now() + self.delay_s))
        )
        with self._lock:
            self._asked[(motor, gen)] = due
        self.inner.stop(motor, gen)  # the motor stops for real; its confirmation waits
        return None

    def events(self) -> list[ExecEvent]:
        out: list[ExecEvent] = []
        now = self.clock.now()
        with self._lock:
            for ev in self.inner.events():
                due = (
                    self._asked.pop((ev.motor, ev.gen), None)
                    if ev.kind is ExecEventKind.STOPPED
                    else None
                )
                if due is not None:
                    self._held.append((due, ev))
                else:
                    out.append(ev)
            out += [ev for due, ev in self._held if due <= now]
            self._held = [(due, ev) for due, ev in self._held if due > now]
        if self.dead and not self._died_reported:
            self._died_reported = True
            out.append(ExecEvent(ExecEventKind.DIED, -1, -1, 0, now, detail="test: executor died"))
        return out

    def events_waiting(self) -> bool:
        """Anything held back (due or not: events() decides), a death not reported yet, or
        the inner executor's."""
        with self._lock:
            held = bool(self._held)
        return held or (self.dead and not self._died_reported) or self.inner.events_waiting()

    def next_deadline(self) -> float | None:
        times = [due for due, _ in self._held]
        if self.dies_at is not None and not self.dead:
            times.append(self.dies_at)
        inner = self.inner.next_deadline()
        if inner is not None:
            times.append(inner)
        times = [t for t in times if t != float("inf")]
        return min(times) if times else None

    def advance(self, now: float) -> None:
        self.inner.advance(now)
        if self.dies_at is not None and now >= self.dies_at and not self.dead:
            self.die()
        if any(due <= now for due, _ in self._held):
            self.on_event()

    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        return self.inner.follow(motor, traj, ramp, gen, endstops, release)

    def committed(self, motor: int, now: float) -> Committed:
        return self.inner.committed(motor, now)

    def service(self, now: float) -> float:
        return self.inner.service(now)

    def planned(self, motor: int) -> bool:
        return self.inner.planned(motor)

    def position(self, motor: int) -> int:
        return self.inner.position(motor)

    def endstop_active(self, motor: int, direction: int) -> bool:
        return self.inner.endstop_active(motor, direction)

    def health(self) -> ExecutorHealth:
        return self.inner.health()

    def start(self) -> None:
        self.inner.start()

    def close(self) -> None:
        self.inner.close()


@dataclass
class StallRig:
    """The engine and the dispatcher of a config over a :class:`SlowToConfirm`."""

    clock: Clock
    hw: Hardware
    ex: SlowToConfirm
    engine: MotionEngine
    dispatcher: Dispatcher

    def send(self, cmd: Command) -> Response:
        return self.dispatcher.handle(cmd)

    def ready(self, motor: int = 0) -> bool:
        return self.send(IsReady(motor)).as_bool

    def position(self, motor: int = 0) -> int:
        return self.send(GetAbsPos(motor)).as_position

    def run(self, dt: float) -> None:
        assert isinstance(self.clock, VirtualClock)
        self.engine.run_until(self.clock.now() + dt)


def stall_rig(
    clock: Clock,
    delay_s: float | None,
    stop_confirm_s: float = STOP_CONFIRM_S,
    config: Config | None = None,
) -> StallRig:
    config = config or parse_config(IN_PROCESS_CONFIG, "test.toml")
    spec = hardware_spec(config)
    params = motor_params(config)
    hw = open_hardware(config.hal.backend, spec, clock)
    ex = SlowToConfirm(build_executor(config, hw, spec, params), clock, delay_s)
    engine = MotionEngine(hw, params, ex, stop_confirm_s=stop_confirm_s)
    return StallRig(clock, hw, ex, engine, Dispatcher(config, engine, hw.pins))
