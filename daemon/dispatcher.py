"""The dispatcher: each command of the command table (motorctl.protocol.commands) to its
handler, the method named after it (MoveToWayPoint: :meth:`Dispatcher.move_to_way_point`),
found by the table's :attr:`~motorctl.protocol.spec.Spec.handler` when the dispatcher is made
(a command without one stops the start); a motion command of the table (its ``motion``) is
made durable before it may start. WaitMoved, whose answer the table says is held, is the
link's: :meth:`Dispatcher.wait_begin`.

Protocol units are converted here (and only here) to steps, step/s and step/s^2, with the
factors the table names for each parameter ([units]); out-of-range values are clamped to the
motor's maximum and counted. Error precedence is PROTOCOL.md section 5:
E1 (frame) -> E2 -> E1 (parameters) -> E6 -> E4 -> E3 -> E0/E5. Each check says why it
refuses, in words, where it decides (:class:`Reject`): the error answers and their reasons are
kept, shown and journalled by :class:`~motorctl.daemon.refusals.Refusals` (``refusals``).

Threads: the link thread calls :meth:`Dispatcher.handle`, :meth:`Dispatcher.wait_begin` and
:meth:`Dispatcher.wait_poll`. They block on the engine lock (short work), on the state file
(SaveHome/SaveWayPoint, outside the lock) and, after a StopMove that stopped a motor hard,
on the executor's confirmation (outside the lock, at most ``engine.stop_confirm_s``): the answer
leaves once the motor has stopped, as the microcontroller's did.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from motorctl.daemon.config import Config
from motorctl.daemon.refusals import Refusals
from motorctl.hal.interfaces import BridgeState, HalError, Pin
from motorctl.motion.engine import MotionEngine, Settled
from motorctl.motion.motor import Motor
from motorctl.motion.types import HomeCmd, MotionCmd, MoveToCmd, Ramp, RunCmd
from motorctl.protocol.codec import (
    COMMANDS,
    Command,
    ConfigPin,
    DcMove,
    ErrorCode,
    GetAbsPos,
    GetPin,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    Response,
    SaveHome,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
)

log = logging.getLogger("motorctl.dispatcher")

E = ErrorCode
OK = Response.ok()
#: why a motion command answers E4 when "moving" cannot be made durable
UNRECORDED = "the state file cannot be written, so a motion cannot be recorded before it starts"


class Persist(Protocol):
    """What the dispatcher needs from persistence (daemon.state.Persistence).

    ``before_motion`` makes "this motor is moving" durable before a motion command may start
    it (False: it cannot, the command answers E4); ``save`` writes a SaveHome/SaveWayPoint
    before its ACK (False: not written, the change is undone and the command answers E4).
    """

    def before_motion(self, index: int) -> bool: ...
    def after_motion(self, index: int) -> None: ...
    def save(self) -> bool: ...


class NoPersistence:
    """Nothing is kept: every hook succeeds (tests of the command table alone)."""

    def before_motion(self, index: int) -> bool:
        return True

    def after_motion(self, index: int) -> None:
        pass

    def save(self) -> bool:
        return True


class Reject(Exception):
    """Raised inside a handler to answer with an error code: why, in words (the reason the
    status and the journal show, and ``motorctl`` prints), the motor it concerns (None: not
    a motor of this machine) and the commands that fix it, in order."""

    def __init__(
        self, code: ErrorCode, reason: str, motor: int | None = None, fix: tuple[str, ...] = ()
    ) -> None:
        super().__init__(f"{code.short}: {reason}")
        self.code = code
        self.reason = reason
        self.motor = motor
        self.fix = fix


@dataclass
class Wait:
    """A held WaitMoved: the motor, the time its timeout expires, and the command."""

    motor: Motor
    deadline: float
    cmd: WaitMoved


def numbers(values: Iterable[int]) -> str:
    """``[0, 1, 2, 5]`` as "0..2, 5" (what a machine has, in a reason)."""
    runs: list[list[int]] = []
    for v in sorted(values):
        if runs and v == runs[-1][1] + 1:
            runs[-1][1] = v
        else:
            runs.append([v, v])
    return ", ".join(str(a) if a == b else f"{a}..{b}" for a, b in runs)


def _fault(m: Motor) -> Reject:
    """E4 for a latched fault: its reason as latched; StopMove clears it (and InitMove homes
    a motor whose position went with it)."""
    fix = ("StopMove", "InitMove") if m.position_lost else ("StopMove",)
    return Reject(E.MOTOR_ERROR, m.fault or "fault", m.index, fix)


class Dispatcher:
    def __init__(
        self,
        config: Config,
        engine: MotionEngine,
        pins: dict[int, Pin],
        persist: Persist | None = None,
    ) -> None:
        self.config = config
        self.engine = engine
        self.pins = pins
        self.persist: Persist = persist or NoPersistence()
        self._undo: Callable[[], None] | None = None
        self._unrecorded = False  # "moving" could not be made durable: no motion may start
        self._settle: Motor | None = None  # a hard stop whose answer waits for the executor
        self.clamped: Counter[str] = Counter()
        self.hardware_errors = 0
        self.refusals = Refusals([m.name for m in config.motors])
        self.table = self._handlers()
        self.factors = self._factors()

    def _handlers(self) -> dict[type[Command], Callable[[Any], Response]]:
        """Each command's handler, the method the table names (WaitMoved, whose answer is
        held: :meth:`wait_begin`); TypeError for a command of the table without one."""
        out: dict[type[Command], Callable[[Any], Response]] = {}
        for cls in COMMANDS:
            if cls.spec.answer.held:
                continue
            handler = getattr(self, cls.spec.handler, None)
            if not callable(handler):
                raise TypeError(f"no handler for {cls.spec.name}: Dispatcher.{cls.spec.handler}")
            out[cls] = handler
        return out

    def _factors(self) -> dict[type[Command], tuple[float, float, float]]:
        """The unit factors of each command's SPEED, ACC and DEC bytes: the [units] settings
        the table names for them (a command with all three)."""
        out: dict[type[Command], tuple[float, float, float]] = {}
        for cls in COMMANDS:
            params = [cls.spec.param(name) for name in ("speed", "acc", "dec")]
            scales = [p.scale for p in params if p is not None and p.scale is not None]
            if len(scales) == 3:
                speed, acc, dec = (float(getattr(self.config.units, s.setting)) for s in scales)
                out[cls] = (speed, acc, dec)
        return out

    # -- entry points -----------------------------------------------------------
    def handle(self, cmd: Command) -> Response:
        """Execute any command but WaitMoved (see :meth:`wait_begin`)."""
        handler = self.table.get(type(cmd))
        if handler is None:
            return self._refuse(cmd, Reject(E.INVALID_COMMAND, "not a command of this daemon"))
        # Motion: "moving" is durable before the motor can start (PROTOCOL.md section 4),
        # written outside the engine lock so the step thread never waits for a disk.
        journalled: int | None = None
        self._settle = None
        engine = self.engine
        if cmd.spec.motion is not None:
            index: int = getattr(cmd, "motor")  # noqa: B009 (a motion command has one)
            if 0 <= index < len(engine.motors):
                if not self.persist.before_motion(index):
                    return self._unrecorded_motion(handler, cmd)
                journalled = index
        try:
            with engine.lock:
                engine.catch_up()  # every event reported before the command, first
                resp = handler(cmd)
        except Reject as r:
            resp = self._refuse(cmd, r)
        except (HalError, OSError) as exc:  # a line or device that failed: never an ACK
            resp = self._hardware_error(cmd, exc)
        finally:
            if journalled is not None:
                self.persist.after_motion(journalled)
        settle, self._settle = self._settle, None
        if settle is not None and resp.ack:
            resp = self._settled(cmd, settle)  # outside the lock: the planner goes on meanwhile
        undo, self._undo = self._undo, None
        if undo is not None and not self.persist.save():
            # SaveHome/SaveWayPoint: no ACK for a change that is not on disk.
            with self.engine.lock:
                undo()
            why = "not saved: the state file cannot be written"
            return self._refuse(cmd, Reject(E.MOTOR_ERROR, why, getattr(cmd, "motor", None)))
        return resp

    def _refuse(self, cmd: Command | None, r: Reject) -> Response:
        """The error answer of ``r``, recorded with its reason (status, journal)."""
        self.refusals.add(r.code, cmd, r.motor, r.reason, r.fix)
        return Response.error(r.code)

    def refused(
        self,
        code: ErrorCode,
        reason: str,
        command: Command | None = None,
        frame: bytes | None = None,
    ) -> None:
        """An error the link session answered itself (a frame that failed its checks, the
        held-frame buffer full, a command that failed): recorded like the others, for its
        motor when it names one of this machine."""
        index = getattr(command, "motor", None)
        motor = index if isinstance(index, int) and 0 <= index < len(self.engine.motors) else None
        self.refusals.add(code, command, motor, reason, frame=frame)

    def _hardware_error(self, cmd: Command, exc: Exception) -> Response:
        """A line or device failed under ``cmd``: E4, and a motor's motion half started is
        stopped, latched with the same reason."""
        self.hardware_errors += 1
        reason = f"hardware error: {exc}"
        index = getattr(cmd, "motor", None)
        motor: int | None = None
        if isinstance(index, int) and 0 <= index < len(self.engine.motors):
            motor = index
            with self.engine.lock:  # a motion half started: stop it, latched
                m = self.engine.motors[index]
                m.latch_fault(reason, self.engine.clock.now(), cause="io_error")
        return self._refuse(cmd, Reject(E.MOTOR_ERROR, reason, motor))

    def _unrecorded_motion(self, handler: Callable[[Any], Response], cmd: Command) -> Response:
        """A motion command whose start cannot be recorded: E4 in E4's place in the order of
        PROTOCOL.md §5 (an unknown waypoint is still E6, a target outside the soft limits
        E1), and nothing starts: the handler runs its checks and :meth:`_submit` refuses."""
        engine = self.engine
        self._unrecorded = True
        try:
            with engine.lock:
                engine.process_events(engine.clock.now())
                handler(cmd)  # every motion handler ends in _submit, which raises
        except Reject as r:
            return self._refuse(cmd, r)
        finally:
            self._unrecorded = False
        return self._refuse(cmd, Reject(E.MOTOR_ERROR, UNRECORDED, getattr(cmd, "motor", None)))

    def _settled(self, cmd: Command, m: Motor) -> Response:
        """A StopMove that stopped ``m`` hard: its answer once the executor confirmed it
        (the position is final and IsReady answers 1 at once). E4 if the executor died
        meanwhile or the motor latched a fault while stopping. After
        ``engine.stop_confirm_s`` without a confirmation (a stalled executor), ACK all the
        same: the stop is on its way and IsReady answers 0 until it took effect.
        """
        outcome = self.engine.settle_stop(m)
        if outcome is Settled.DIED:
            why = "the step executor died before confirming the stop"
            return self._refuse(cmd, Reject(E.MOTOR_ERROR, why, m.index))
        if m.fault is not None:  # latched while the stop took effect (a driver fault): it
            return self._refuse(cmd, _fault(m))  # remains, as for a StopMove on a faulted motor
        if outcome is Settled.TIMED_OUT:
            log.warning(
                "motor %d: the step executor did not confirm the hard stop within "
                "%.0f ms (stalled?): StopMove answered anyway, IsReady answers 0 until "
                "it does; later hard stops are not waited for while it is unconfirmed",
                m.index,
                self.engine.stop_confirm_s * 1000,
                extra={"MOTOR": m.index, "COMMAND": "StopMove"},
            )
        return OK

    def link_silent(self, *, hard: bool, reason: str) -> list[str]:
        """The host fell silent ([link] timeout_ms; :mod:`motorctl.daemon.link.silence`): every
        motor in motion stops and latches ``reason``, the DC motor brakes; what was
        stopped, for the log."""
        engine = self.engine
        with engine.lock:
            engine.process_events(engine.clock.now())
            return engine.fault_stop_moving(reason, hard, engine.clock.now(), cause="link_timeout")

    def wait_begin(self, cmd: WaitMoved, now: float) -> Response | Wait:
        """A WaitMoved: an answer now, or a :class:`Wait` to hold the link on."""
        try:
            with self.engine.lock:
                self.engine.process_events(now)
                m = self._motor(cmd.motor)
                self._not_faulted(m)
                if m.idle:
                    return OK
        except Reject as r:
            return self._refuse(cmd, r)
        if cmd.timeout_ms == 0:
            why = "still moving; TIMEOUT 0 answers at once"
            return self._refuse(cmd, Reject(E.MOTOR_NOT_READY, why, m.index))
        return Wait(m, now + cmd.timeout_ms / 1000.0, cmd)

    def wait_poll(self, wait: Wait, now: float) -> Response | None:
        """The held WaitMoved's answer once it has one: ACK, E4 on a fault, E3 at timeout."""
        with self.engine.lock:
            self.engine.process_events(now)
            m = wait.motor
            if m.fault is not None:
                return self._refuse(wait.cmd, _fault(m))
            if m.idle:
                return OK
        if now >= wait.deadline:
            why = f"still moving after {wait.cmd.timeout_ms} ms (WaitMoved's TIMEOUT)"
            return self._refuse(wait.cmd, Reject(E.MOTOR_NOT_READY, why, m.index))
        return None

    # -- checks, in precedence order ----------------------------------------------
    def _motor(self, index: int) -> Motor:
        motors = self.engine.motors
        if not 0 <= index < len(motors):
            has = f"motors {numbers(range(len(motors)))}" if motors else "no motors"
            raise Reject(E.INVALID_ADDRESS, f"no motor {index} (this machine has {has})")
        return motors[index]

    def _pin(self, number: int) -> Pin:
        pin = self.pins.get(number)
        if pin is None:
            has = f"pins {numbers(self.pins)}" if self.pins else "no pins"
            raise Reject(E.INVALID_ADDRESS, f"no pin {number} (this machine has {has})")
        return pin

    @staticmethod
    def _not_faulted(m: Motor) -> None:
        if m.fault is not None:
            raise _fault(m)

    @staticmethod
    def _position_known(m: Motor) -> None:
        if m.position_lost:
            why = "its position is lost (not homed since it was last known)"
            raise Reject(E.MOTOR_ERROR, why, m.index, ("InitMove",))

    @staticmethod
    def _idle(m: Motor) -> None:
        if not m.idle:
            why = f"not idle ({m.state.value}, {len(m.queue)} queued): it must be at rest"
            raise Reject(E.MOTOR_NOT_READY, why, m.index)

    def _submit(self, m: Motor, cmd: MotionCmd) -> Response:
        if self._unrecorded:
            raise Reject(E.MOTOR_ERROR, UNRECORDED, m.index)  # before E0: E4 comes first
        if m.queue_full:
            why = f"motion queue full ({m.params.queue_depth} commands behind the running one)"
            raise Reject(E.FULL_BUFFER, why, m.index)
        m.submit(cmd, self.engine.clock.now())
        self.engine.wake.set()
        return OK

    def _target(self, m: Motor, position: int) -> None:
        if not m.target_allowed(position):
            p = m.params
            why = f"target {position} is outside the soft limits {p.soft_min}..{p.soft_max}"
            raise Reject(E.INVALID_COMMAND, why, m.index)
        counted = m.counted_range()
        if counted is not None and not counted[0] <= position <= counted[1]:
            why = (
                f"target {position} is outside what the motor's driver chip counts from its "
                f"zero: {counted[0]}..{counted[1]}"
            )
            raise Reject(E.INVALID_COMMAND, why, m.index)

    # -- unit conversion --------------------------------------------------------------
    def _ramp(self, m: Motor, c: Command, raw: tuple[int, int, int], default_speed: float) -> Ramp:
        """A command's SPEED, ACC and DEC bytes (``raw``) in step/s and step/s^2, by the unit
        factors the table names for them; 0: the default (``default_speed``, the motor's
        ramps)."""
        mc = self.config.motors[m.index]
        f_speed, f_acc, f_dec = self.factors[type(c)]
        speed, acc, dec = raw
        return Ramp(
            self._scale("speed", speed, f_speed, default_speed, mc.max_speed),
            self._scale("acc", acc, f_acc, mc.default_accel, mc.max_accel),
            self._scale("dec", dec, f_dec, mc.default_decel, mc.max_accel),
        )

    def _scale(self, what: str, raw: int, factor: float, default: float, limit: float) -> float:
        if raw == 0:
            return default
        value = raw * factor
        if value > limit:
            self.clamped[what] += 1
            return limit
        return value

    # -- the handlers, one per command of the table (named by it) ---------------------------
    def init_move(self, c: InitMove) -> Response:
        m = self._motor(c.motor)
        self._not_faulted(m)  # a lost position is what homing is for
        homing = self.config.motors[m.index].homing.speed
        ramp = self._ramp(m, c, (c.speed, c.acc, c.dec), homing)
        return self._submit(m, HomeCmd(1 if c.direction else -1, ramp))

    def move_to(self, c: MoveTo) -> Response:
        m = self._motor(c.motor)
        self._target(m, c.position)
        self._not_faulted(m)
        self._position_known(m)
        ramp = self._ramp(m, c, (c.speed, c.acc, c.dec), self.config.motors[m.index].default_speed)
        return self._submit(m, MoveToCmd(c.position, ramp, 1 if c.direction else -1))

    def is_ready(self, c: IsReady) -> Response:
        m = self._motor(c.motor)
        self._not_faulted(m)
        return Response.boolean(m.idle)

    def move(self, c: Move) -> Response:
        m = self._motor(c.motor)
        self._not_faulted(m)
        self._position_known(m)
        ramp = self._ramp(m, c, (c.speed, c.acc, c.dec), self.config.motors[m.index].default_speed)
        return self._submit(m, RunCmd(1 if c.direction else -1, ramp))

    def stop_move(self, c: StopMove) -> Response:
        m = self._motor(c.motor)
        died = self.engine.executor_died
        if died is not None:  # nothing moves any more: the fault stays latched
            why = f"the step executor died ({died}): the daemon must be restarted"
            raise Reject(E.MOTOR_ERROR, why, m.index)
        if not m.stop(c.hard, self.engine.clock.now()):
            why = f"{m.fault}: the driver still reports it"
            raise Reject(E.MOTOR_ERROR, why, m.index)
        self.engine.wake.set()
        if m.stopping:  # stopped hard (also a soft stop that had no ramp to follow)
            self._settle = m
        return OK

    def get_abs_pos(self, c: GetAbsPos) -> Response:
        return Response.position(self._motor(c.motor).position)

    def set_pin(self, c: SetPin) -> Response:
        pin = self._pin(c.pin)
        if not pin.is_output:
            raise Reject(E.INVALID_COMMAND, f"pin {c.pin} is an input", None, ("ConfigPin",))
        pin.write(c.high)
        return OK

    def get_pin(self, c: GetPin) -> Response:
        return Response.boolean(self._pin(c.pin).read())

    def config_pin(self, c: ConfigPin) -> Response:
        self._pin(c.pin).configure(c.output)
        return OK

    def save_home(self, c: SaveHome) -> Response:
        m = self._motor(c.motor)
        self._not_faulted(m)
        self._position_known(m)
        self._idle(m)
        old = m.home
        m.home = m.position

        def undo() -> None:
            m.home = old

        self._undo = undo
        return OK

    def go_home(self, c: GoHome) -> Response:
        m = self._motor(c.motor)
        self._target(m, m.home)
        self._not_faulted(m)
        self._position_known(m)
        mc = self.config.motors[m.index]
        ramp = Ramp(mc.default_speed, mc.default_accel, mc.default_decel)
        return self._submit(m, MoveToCmd(m.home, ramp, 1))

    def save_way_point(self, c: SaveWayPoint) -> Response:
        m = self._motor(c.motor)
        self._not_faulted(m)
        self._position_known(m)
        self._idle(m)
        if len(m.waypoints) >= m.params.max_waypoints:
            why = f"waypoint table full ({m.params.max_waypoints} waypoints)"
            raise Reject(E.FULL_WAYPOINT_BUFFER, why, m.index)
        m.waypoints.append(m.position)
        count = len(m.waypoints)

        def undo() -> None:
            del m.waypoints[count - 1 :]

        self._undo = undo
        return Response.ok(bytes([len(m.waypoints) - 1]))

    def move_to_way_point(self, c: MoveToWayPoint) -> Response:
        m = self._motor(c.motor)
        if c.waypoint >= len(m.waypoints):
            saved = len(m.waypoints)
            has = f"saved: {numbers(range(saved))}" if saved else "none saved"
            why = f"no waypoint {c.waypoint}; {has}"
            raise Reject(E.INVALID_WAYPOINT, why, m.index)
        target = m.waypoints[c.waypoint]
        self._target(m, target)
        self._not_faulted(m)
        self._position_known(m)
        ramp = self._ramp(m, c, (c.speed, c.acc, c.dec), self.config.motors[m.index].default_speed)
        return self._submit(m, MoveToCmd(target, ramp, 1))

    def dc_move(self, c: DcMove) -> Response:
        dc = self.config.dc
        if dc is None or self.engine.dc is None:
            raise Reject(E.INVALID_ADDRESS, "no DC motor configured")
        hiz = c.hiz != dc.invert_hiz
        end = BridgeState.COAST if hiz else BridgeState.BRAKE
        time_ms = min(c.time_ms, dc.max_time_ms)
        self.engine.dc_run(c.direction, time_ms / 1000.0, end)
        return OK
