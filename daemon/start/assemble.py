"""The assembler: a config becomes a running daemon, everything it runs built here.

The one place where the names a config gives become objects, as python-can's interface.py
makes a bus of a name: the hardware backend and its layers by name through the HAL's
registry (:func:`hardware_spec`: the config as the HAL's picklable spec), the step executor
the config asks for (:func:`build_executor`: process, running the step core ``[step_thread]
core`` names; thread; or none when every motor's driver runs its own ramp), the motion
engine, the state file and the dispatcher (:meth:`Daemon.build`: everything behind the
serial port); then what serves it (:func:`build_served`): the port (a PTY, or the UART,
daemon/link/), the trace and the link's silence watch (daemon/start/link_parts.py), the link,
the status socket, systemd's STATUS= line, the motor events' journal entries and the
watchdog's idea of progress.
:meth:`Daemon._on_motor_event` is the one listener of the motors' events: it wakes each
part that wants to know. It knows the HAL only by its interfaces: what some hardware can
do it asks for (``RampDriver``, ``StepperDriver.stats``, ``Hardware.persistent_state``),
never a backend's class.

A part that cannot be built stops the start with a :class:`StartupError` (or the HAL's
message), and what was opened before it is closed again, each close registered once, as
it is opened, on one ``ExitStack``; :meth:`Served.close` closes what served after
daemon/start/serve.py's shutdown.

Threads: everything here runs on the main thread at start-up, before the daemon serves,
except :meth:`Daemon.status` (the status server's thread and the STATUS= line's: reads
snapshots, never the motion lock) and :meth:`Daemon._on_motor_event` (whichever thread the
engine reports from, its lock held: no I/O).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from motorctl.daemon.config import Config, ConfigError, MotorConfig
from motorctl.daemon.config.model import MICROSTEPS_UNSAID
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.errors import StartupError
from motorctl.daemon.instance import Owned
from motorctl.daemon.link.devwatch import NOT_BACK, PathWatch
from motorctl.daemon.link.loop import Link
from motorctl.daemon.link.ports import PtySlave, open_pty
from motorctl.daemon.link.serialport import DeviceError, SerialDevice
from motorctl.daemon.link.silence import check_timeout
from motorctl.daemon.service import (
    MotorEventLog,
    ProgressWatch,
    StatusLine,
    Watchdog,
    watchdog_interval,
)
from motorctl.daemon.start.link_parts import cpu_parts, open_trace, silence_watch
from motorctl.daemon.start.timeline import StartTimeline
from motorctl.daemon.state.persistence import Persistence
from motorctl.daemon.state.records import MotorIdentity, geometry_fingerprint
from motorctl.daemon.state.writer import StateWriter
from motorctl.daemon.status.document import StatusDocument, status_document, summary_line
from motorctl.daemon.status.server import StatusServer
from motorctl.hal.interfaces import Clock, HalError, Hardware, MonotonicClock, RampDriver
from motorctl.hal.registry import driver_spec, open_hardware
from motorctl.hal.spec import AxisSpec, HardwareSpec, PinSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.base import Executor
from motorctl.motion.executors.planner import axis_limits
from motorctl.motion.executors.process.parent import ProcessStepExecutor
from motorctl.motion.executors.process.start import WaitingInterpreter
from motorctl.motion.executors.split import with_ramp_motors
from motorctl.motion.executors.thread import ThreadStepExecutor
from motorctl.motion.motor import Motor
from motorctl.motion.rt import GcPolicy, RealtimeOptions
from motorctl.motion.types import HomingParams, MotorParams
from motorctl.protocol.codec import wrap24

if TYPE_CHECKING:  # imported when a trace is asked for (link_parts.open_trace)
    from motorctl.daemon.link.recorder import TraceRecorder

log = logging.getLogger("motorctl")

#: the planner's step-time error bound (segments' reproduction of exact step times)
STEP_ERROR_S = 5e-6


def hardware_spec(config: Config) -> HardwareSpec:
    """What the backend builds; every backend's config sections travel along (`sections`),
    and each motor's driver chip as its layer reads it from them (``registry.driver_spec``)."""
    st = config.step_thread
    axes = tuple(
        AxisSpec(
            invert_dir=m.invert_dir,
            endstop_active_low=m.endstop.active_low,
            endstop_debounce_s=m.endstop.debounce_ms / 1000.0,
            name=m.name,
            driver=driver_spec(m),
            dir_setup_s=st.dir_setup_us / 1e6,
            sections=m.sections,
        )
        for m in config.motors
    )
    pins = tuple(
        PinSpec(p.number, p.is_output, p.initial, sections=p.sections) for p in config.pins
    )
    return HardwareSpec(axes, pins, dc=config.dc is not None, sections=config.sections)


def motor_params(config: Config) -> list[MotorParams]:
    st = config.step_thread
    return [
        MotorParams(
            name=m.name,
            steps_per_rev=m.steps_per_rev,
            queue_depth=m.queue_depth,
            max_waypoints=m.max_waypoints,
            soft_min=m.soft_limit_min,
            soft_max=m.soft_limit_max,
            homing=HomingParams(
                source=m.homing.source,
                max_travel=m.homing.max_travel,
                pull_off=m.homing.pull_off,
                second_speed=m.homing.second_speed,
            ),
            debounce_s=m.endstop.debounce_ms / 1000.0,
            dir_setup_s=st.dir_setup_us / 1e6,
            pulse_s=st.step_pulse_us / 1e6,
            max_speed=m.max_speed,
            start_speed=m.start_speed,
            microsteps=motor_microsteps(m),
            counter_range=counter_range(m),
            max_lag_full_steps=m.max_lag_full_steps,
            host_position=wrap24,
        )
        for m in config.motors
    ]


def counter_range(m: MotorConfig) -> tuple[int, int] | None:
    """The range of the motor's driver chip's own position counter (a dSPIN's ABS_POS),
    None without one."""
    driver = driver_spec(m)
    return None if driver is None else driver.counter_range


def motor_microsteps(m: MotorConfig) -> int:
    """Microsteps per full step: its own key, else its driver chip's (``[motors.tmc]``),
    else MICROSTEPS_UNSAID."""
    known = known_microsteps(m)
    return MICROSTEPS_UNSAID if known is None else known


def known_microsteps(m: MotorConfig) -> int | None:
    """Microsteps per full step when the config says: its own key, else its driver chip's;
    None when neither does."""
    if m.microsteps is not None:
        return m.microsteps
    driver = driver_spec(m)
    return None if driver is None else driver.microsteps


def motor_geometry(config: Config, m: MotorConfig) -> dict[str, object]:
    """What gives a motor's saved positions their meaning: a change restores nothing."""
    driver = driver_spec(m)
    return {
        "steps_per_rev": m.steps_per_rev,
        "invert_dir": m.invert_dir,
        "backend": config.hal.backend,
        "microsteps": None if driver is None else driver.microsteps,
    }


def motor_identities(config: Config) -> list[MotorIdentity]:
    """Names and geometry fingerprints: a saved motor is restored only onto its own match."""
    return [
        MotorIdentity(
            name=m.name,
            fingerprint=geometry_fingerprint(motor_geometry(config, m)),
            max_waypoints=m.max_waypoints,
            steps_per_rev=m.steps_per_rev,
        )
        for m in config.motors
    ]


@dataclass
class Daemon:
    """Everything behind the serial port, wired together (no serial port yet)."""

    config: Config
    state_dir: Path
    clock: Clock
    hw: Hardware
    engine: MotionEngine
    dispatcher: Dispatcher
    persistence: Persistence
    gc_policy: GcPolicy = field(default_factory=GcPolicy)
    link: Link | None = None
    trace: TraceRecorder | None = None
    started: float = field(default_factory=time.monotonic)
    #: served only (:func:`build_served`): motor events for the journal, systemd's STATUS=
    #: line and the status socket, each told of the motors' events
    events: MotorEventLog | None = None
    status_line: StatusLine | None = None
    status_server: StatusServer | None = None

    @classmethod
    def build(
        cls,
        config: Config,
        state_dir: Path,
        clock: Clock | None = None,
        executor_process: WaitingInterpreter | None = None,
        undo: contextlib.ExitStack | None = None,
        timeline: StartTimeline | None = None,
    ) -> Daemon:
        """Everything behind the serial port; ``executor_process``: see
        :func:`motorctl.daemon.start.main.main`. What it opens (the hardware, the step executor)
        registers its close on ``undo``, the caller's stack for a later part's failure; by
        default on its own, closed when a part of the daemon fails. ``timeline``: marked as
        each part is built (daemon/start/timeline.py)."""
        timeline = timeline or StartTimeline("build")
        clock = clock or MonotonicClock()
        make_state_dir(state_dir)
        spec = hardware_spec(config)
        if config.step_thread.executor == "process" and not clock.is_virtual:
            spec = replace(spec, options={**spec.options, "executor_process": True})
        params = motor_params(config)
        with contextlib.ExitStack() as own:
            opened = own if undo is None else undo
            try:
                hw = open_hardware(config.hal.backend, spec, clock)
            except HalError as exc:
                raise StartupError(str(exc)) from exc
            opened.callback(quietly(hw.close))  # the lines, e.g. the mock's shared memory
            timeline.mark("hardware")
            try:
                executor = build_executor(config, hw, spec, params, executor_process)
            except HalError as exc:
                raise StartupError(str(exc)) from exc
            opened.callback(quietly(executor.close))  # e.g. the process executor's memory
            timeline.mark("executor handed over")
            engine = MotionEngine(
                hw,
                params,
                executor,
                stop_confirm_s=config.step_thread.stop_confirm_ms / 1000.0,
            )
            files_dir = state_files_dir(config, state_dir)
            make_state_dir(files_dir, state_dir_option(config, state_dir))
            persistence = Persistence(
                files_dir,
                motor_identities(config),
                engine,
                (hw.persistent_state, hw.restore_persistent_state),
            )
            dispatcher = Dispatcher(config, engine, hw.pins, persist=persistence)
            daemon = cls(config, state_dir, clock, hw, engine, dispatcher, persistence)
            persistence.restore()
            persistence.open()
            timeline.mark("state")
            own.pop_all()  # built: nothing to close
        engine.listeners.append(daemon._on_motor_event)  # the one listener
        return daemon

    @property
    def writer(self) -> StateWriter:
        return self.persistence.writer

    def status(self, histogram: bool = False) -> dict[str, Any]:
        """The status document (daemon/status/document.py)."""
        return status_document(self, histogram)

    def _on_motor_event(self, motor: Motor, event: str) -> None:
        """The motors' one listener: a motor started, stopped, faulted, ... Runs with the
        engine lock held, often on the step thread: no I/O here, only requests and pokes."""
        self.writer.request()
        if event == "start":
            self.gc_policy.motion(True)
        elif not self.engine.any_active:
            self.gc_policy.motion(False)
        if self.link is not None:
            self.link.wake()  # a held WaitMoved looks again
        if self.events is not None:
            self.events.record(
                motor.index,
                motor.params.name,
                event,
                motor.fault,
                motor.fault_cause,
                motor.position_lost,
            )
        if self.status_line is not None:
            self.status_line.poke()
        if self.status_server is not None:
            self.status_server.poke()  # subscribers see a start, stop or fault at once


def quietly(close: Callable[[], None]) -> Callable[[], None]:
    """``close`` for a start that failed: its own error is not the one to report."""

    def run() -> None:
        with contextlib.suppress(Exception):
            close()

    return run


@dataclass(frozen=True)
class ServeOptions:
    """Where the daemon serves and keeps its files: the command line's say
    (daemon/start/main.py)."""

    state_dir: Path
    pty: Path | None = None  # --pty: a new PTY, this path a link to it
    port: str | None = None  # --port: a UART's path
    baud: int = 115200
    trace: Path | None = None  # --trace: overrides [trace] file


@dataclass
class Served:
    """A daemon built to serve (:func:`build_served`), nothing started yet: daemon/start/serve.py
    starts it, serves, shuts it down and closes it (:meth:`close`)."""

    daemon: Daemon
    link: Link
    status: StatusServer
    line: StatusLine
    where: str  # the port in words, for the READY line
    uart: SerialDevice | None  # --port's device (the link opens it again by its path)
    fd: int  # --pty: the PTY's master, closed after the link
    recorder: TraceRecorder | None
    watchdog: Watchdog | None  # only under systemd's WatchdogSec

    def close(self) -> None:
        """After the shutdown (which closed the step executor): the watchdog, the status
        socket, the link, the trace, the port and the hardware, in that order."""
        if self.watchdog is not None:
            self.watchdog.stop()
        self.status.close()
        self.link.close()
        if self.recorder is not None:
            self.recorder.close()
        if self.uart is not None:
            self.uart.close()
        else:
            os.close(self.fd)
        self.daemon.hw.close()


def build_served(
    config: Config,
    options: ServeOptions,
    owned: Owned,
    executor_process: WaitingInterpreter | None = None,
    timeline: StartTimeline | None = None,
) -> Served:
    """Everything the daemon runs, built and wired, in the order a start must fail in: the
    serial device before the state (one that is there but cannot be used stops the start
    before the state is restored and written again; one that is not there yet is served
    when it appears), the daemon behind the port, the PTY (its link recorded in ``owned``),
    the trace, the link, the status socket. A part that fails closes what was opened
    before it (ConfigError, StartupError or the HAL's error). ``timeline``: marked as each
    part is built (daemon/start/timeline.py)."""
    timeline = timeline or StartTimeline("build")
    why = check_timeout(config.link.timeout_ms, options.baud)
    if why is not None:
        raise ConfigError(f"{config.source}: {why}")
    with contextlib.ExitStack() as undo:
        uart, fd = open_uart(options)
        if uart is not None:
            undo.callback(quietly(uart.close))
        daemon = Daemon.build(
            config,
            options.state_dir,
            executor_process=executor_process,
            undo=undo,
            timeline=timeline,
        )
        pty: PtySlave | None = None
        if options.pty is not None:
            fd, name = open_pty(options.pty)
            undo.callback(quietly(lambda: os.close(fd)))
            owned.symlink(options.pty, name)
            pty = PtySlave(fd, name)
            undo.callback(quietly(pty.close))
            where = f"{options.pty} -> {name}"
        else:
            where = f"{options.port} at {options.baud} baud"
            if fd < 0:
                where += " (not there yet: served when it appears)"
        timeline.mark("PTY" if options.pty is not None else "port")
        recorder = open_trace(options.trace, config, where)
        if recorder is not None:
            undo.callback(quietly(recorder.close))
        c = config.link
        link = Link(
            fd,
            daemon.dispatcher,
            c.codec_options(),
            c.frame_gap_ms / 1000.0,
            c.held_frames,
            pty=pty,
            device=uart,
            notice=None if uart is None else PathWatch(uart.path),
            watch=silence_watch(config, daemon.dispatcher, time.monotonic()),
            recorder=recorder,
            parts=cpu_parts(),
        )
        undo.callback(quietly(link.close))
        daemon.link = link
        daemon.trace = recorder
        timeline.mark("link")
        status = open_status(options.state_dir, daemon)
        timeline.mark("status socket")
        undo.pop_all()  # built: from here on, Served.close closes it
    events = MotorEventLog()
    refusals = daemon.dispatcher.refusals

    def journal() -> None:  # off the link and step threads: their queued journal lines
        events.flush()
        refusals.flush()  # what the error answers' rate limit held back

    line = StatusLine(lambda: summary_line(daemon.status()), before=journal)
    daemon.events, daemon.status_line, daemon.status_server = events, line, status
    daemon.writer.on_change = line.poke
    interval = watchdog_interval()
    watchdog = Watchdog(interval, progress_watch(daemon, link).healthy) if interval else None
    return Served(daemon, link, status, line, where, uart, fd, recorder, watchdog)


def open_uart(options: ServeOptions) -> tuple[SerialDevice | None, int]:
    """``--port``'s device and its descriptor (-1: not there yet, served when it appears);
    (None, -1) without ``--port``. StartupError when it is there but cannot be used."""
    if options.port is None:
        return None, -1
    uart = SerialDevice(options.port, options.baud)
    try:
        return uart, uart.open()
    except DeviceError as exc:
        if exc.errno not in NOT_BACK:
            raise StartupError(str(exc)) from exc
        return uart, -1


def open_status(state_dir: Path, daemon: Daemon) -> StatusServer:
    """The status socket ``status.sock`` in ``state_dir``, serving ``daemon``'s document."""
    path = state_dir / "status.sock"
    try:
        return StatusServer(path, StatusDocument(daemon))  # its reads' own document
    except OSError as exc:
        raise StartupError(f"cannot serve the status socket {path}: {exc.strerror or exc}") from exc


def state_files_dir(config: Config, state_dir: Path) -> Path:
    """Where state.json lives: [state] directory, else the --state-dir (docs/service.md)."""
    return Path(config.state.directory) if config.state.directory else state_dir


def state_dir_option(config: Config, state_dir: Path) -> str:
    """What names the state files' directory (:func:`state_files_dir`), for a message's
    fix: ``[state] directory`` and the config file, or ``--state-dir``."""
    if state_files_dir(config, state_dir) == state_dir:
        return "--state-dir"
    return f"[state] directory in {config.source}"


def make_state_dir(state_dir: Path, option: str = "--state-dir") -> None:
    """The state directory made (with its parents) and found writable; StartupError
    naming it, why not, and ``option`` (what named it) to change."""
    fix = f"give {option} a writable directory"
    try:
        state_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:  # a file, a FIFO, a dangling link, ...: mkdir's word is wrong
        raise StartupError(
            f"cannot create state directory {state_dir}: something that is not a directory "
            f"is there; {fix}"
        ) from None
    except OSError as exc:
        raise StartupError(
            f"cannot create state directory {state_dir}: {exc.strerror}; {fix}"
        ) from exc
    if not os.access(state_dir, os.W_OK | os.X_OK):
        raise StartupError(f"state directory {state_dir} is not writable; {fix}")


def build_executor(
    config: Config,
    hw: Hardware,
    spec: HardwareSpec,
    params: list[MotorParams],
    process: WaitingInterpreter | None = None,
) -> Executor:
    """The step executor the config asks for (only it runs real-time and locks memory), for
    the motors ``spec.stepped()`` names; the motors whose driver runs its own ramp (the
    HAL's RampDriver: a TMC5160 with ``[motors.tmc] mode = "ramp"``) go to a RampExecutor
    instead and are not the step executor's at all (no STEP/DIR, no slot). Without stepped
    motors there is no step executor (nothing to run in real time). ``process``: an
    executor process started early (daemon/start/launch.py), the process executor's; ended here
    when the config has no use for it."""
    st = config.step_thread
    if st.core == "compiled" and st.executor == "thread":
        raise StartupError(
            '[step_thread] core = "compiled" runs in the process executor only; set '
            'executor = "process", or core = "auto" (the thread executor runs the Python core)'
        )
    stepped = spec.stepped()
    drivers = [s.driver for s in hw.steppers]
    ramp = [i for i, d in enumerate(drivers) if isinstance(d, RampDriver)]
    if set(ramp) | set(stepped) != set(range(len(drivers))) or set(ramp) & set(stepped):
        raise StartupError(f"ramp motors {ramp} and stepped motors {list(stepped)} disagree")
    limits = axis_limits(
        [params[i] for i in stepped],
        STEP_ERROR_S,
        slide_after_s=st.late_threshold_us / 1e6,
        lag_faults=hw.motors_lose_steps,
    )
    rt = RealtimeOptions(st.priority, st.lock_memory, st.cpu)
    steps: Executor | None = None
    if not stepped:
        pass
    elif hw.clock.is_virtual:  # tests drive a virtual clock themselves: the thread kind's job
        steps = ThreadStepExecutor(hw, config.hal.backend, spec, limits, max_error_s=0.0)
    elif st.executor == "process":
        steps = ProcessStepExecutor(
            hw,
            config.hal.backend,
            spec,
            limits,
            ahead_s=st.ahead_ms / 1000.0,
            lead_s=st.lead_ms / 1000.0,
            max_error_s=STEP_ERROR_S,
            spin_s=st.spin_us / 1e6,
            late_threshold_s=st.late_threshold_us / 1e6,
            rt=rt,
            process=process,
            core=st.core,
        )
    else:
        steps = ThreadStepExecutor(
            hw,
            config.hal.backend,
            spec,
            limits,
            ahead_s=st.ahead_ms / 1000.0,
            lead_s=st.lead_ms / 1000.0,
            max_error_s=STEP_ERROR_S,
            spin_s=st.spin_us / 1e6,
            late_threshold_s=st.late_threshold_us / 1e6,
            rt=rt,
        )
        log.info("step core: python (the thread executor runs the Python core)")
    if process is not None:
        process.dismiss()  # no process executor after all (a no-op when it took it)
    return with_ramp_motors(steps, drivers, hw.clock)  # polled as the ramp drivers ask


def progress_watch(daemon: Daemon, link: Link) -> ProgressWatch:
    """WATCHDOG=1 only while the link loop, the planner, the step executor and the state
    writer each made progress since the watchdog's previous look."""
    engine, writer = daemon.engine, daemon.writer

    def executor() -> int | None:
        h = engine.executor.health()
        return h.progress if h.alive else None

    def planner() -> int | None:
        return engine.planner_progress if engine.threads_alive else None

    def state_writer() -> int | None:
        return writer.writes if writer.pending else ProgressWatch.IDLE

    return ProgressWatch(
        {
            "link loop": lambda: link.turns,
            "planner": planner,
            "step executor": executor,
            "state writer": state_writer,
        },
        pokes=(link.poke,),
    )
