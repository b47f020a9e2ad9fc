"""The assembler: a config becomes a running daemon (everything behind the serial port).

The one place where the names a config gives become objects, as python-can's interface.py
makes a bus of a name: the hardware backend and its layers by name through the HAL's
registry (:func:`hardware_spec`: the config as the HAL's picklable spec), the step executor
the config asks for (:func:`build_executor`: process, running the step core ``[step_thread]
core`` names; thread; or none when every motor's driver runs its own ramp), the motion
engine, the state file and the dispatcher
(:meth:`Daemon.build`); and the link's parts (:func:`silence_watch`, :func:`open_trace`,
:func:`progress_watch`). It knows the HAL only by its interfaces: what some hardware can
do it asks for (``RampDriver``, ``StepperDriver.stats``, ``Hardware.persistent_state``),
never a backend's class.

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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from motorctl import __version__
from motorctl.daemon.config import Config, MotorConfig
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.link import Link
from motorctl.daemon.service import ProgressWatch
from motorctl.daemon.silence import SilenceWatch
from motorctl.daemon.state import MotorIdentity, Persistence, StateWriter, geometry_fingerprint
from motorctl.daemon.trace import TraceRecorder
from motorctl.hal.interfaces import Clock, HalError, Hardware, MonotonicClock, Pin, RampDriver
from motorctl.hal.registry import driver_spec, open_hardware
from motorctl.hal.spec import AxisSpec, HardwareSpec, PinSpec
from motorctl.motion.dc import DcMotor
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executor_chip_ramp import RampExecutor, with_ramp_motors
from motorctl.motion.executor_process import ProcessStepExecutor
from motorctl.motion.executor_process_start import ExecutorProcess
from motorctl.motion.executor_seam import Executor
from motorctl.motion.executor_thread import ThreadStepExecutor
from motorctl.motion.motor import Motor
from motorctl.motion.profile import Trajectory
from motorctl.motion.rt import GcPolicy, RealtimeOptions
from motorctl.motion.step_planner import axis_limits
from motorctl.motion.types import HomingParams, MotorParams
from motorctl.protocol.capture import CaptureInfo
from motorctl.protocol.codec import wrap24

log = logging.getLogger("motorctl")

#: the planner's step-time error bound (segments' reproduction of exact step times)
STEP_ERROR_S = 5e-6


class StartupError(Exception):
    """Something the user must fix before the daemon can start; the message says what."""


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
            max_lag_full_steps=m.max_lag_full_steps,
            host_position=wrap24,
        )
        for m in config.motors
    ]


def motor_microsteps(m: MotorConfig) -> int:
    """Microsteps per full step: its own key, else its driver chip's (``[motors.tmc]``),
    else 16."""
    known = known_microsteps(m)
    return 16 if known is None else known


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

    @classmethod
    def build(
        cls,
        config: Config,
        state_dir: Path,
        clock: Clock | None = None,
        executor_process: ExecutorProcess | None = None,
    ) -> Daemon:
        """Everything behind the serial port; ``executor_process``: see
        :func:`motorctl.daemon.main.main`."""
        clock = clock or MonotonicClock()
        make_state_dir(state_dir)
        spec = hardware_spec(config)
        if config.step_thread.executor == "process" and not clock.is_virtual:
            spec = replace(spec, options={**spec.options, "executor_process": True})
        params = motor_params(config)
        try:
            hw = open_hardware(config.hal.backend, spec, clock)
        except HalError as exc:
            raise StartupError(str(exc)) from exc
        executor: Executor | None = None
        try:  # what is open is closed again when a later part fails (lines, the executor)
            try:
                executor = build_executor(config, hw, spec, params, executor_process)
            except HalError as exc:
                raise StartupError(str(exc)) from exc
            engine = MotionEngine(
                hw,
                params,
                executor,
                driver_poll_s=config.step_thread.driver_poll_ms / 1000.0,
                stop_confirm_s=config.step_thread.stop_confirm_ms / 1000.0,
            )
            files_dir = state_files_dir(config, state_dir)
            make_state_dir(files_dir)
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
        except BaseException:
            if executor is not None:
                with contextlib.suppress(Exception):
                    executor.close()
            with contextlib.suppress(Exception):
                hw.close()
            raise
        engine.listeners.append(daemon._on_motor_event)
        return daemon

    @property
    def writer(self) -> StateWriter:
        return self.persistence.writer

    def _on_motor_event(self, motor: Motor, event: str) -> None:
        # Runs with the engine lock held, often on the step thread: no I/O here.
        self.writer.request()
        if event == "start":
            self.gc_policy.motion(True)
        elif not self.engine.any_active:
            self.gc_policy.motion(False)
        if self.link is not None:
            self.link.wake()

    # -- status --------------------------------------------------------------------
    def status(self, histogram: bool = False) -> dict[str, Any]:
        """A snapshot for the status socket, taken WITHOUT the motion lock: each field is
        read whole (the executor's counters and histogram are its own snapshots), so a
        status read never delays planning, let alone a step. Its cost is bounded (the
        lateness percentiles come from the histogram's blocks), except ``histogram``: the
        step edges' whole lateness histogram, ``steps.histogram_us`` (non-empty 1 us bins,
        up to 20,001), for the benchmarks that ask for it."""
        executor = self.engine.executor
        motors: list[dict[str, Any]] = [
            {
                "index": m.index,
                "name": m.params.name,
                "state": m.state.value,
                "position": m.position,
                "queued": len(m.queue),
                "fault": m.fault,
                "position_lost": m.position_lost,
                "waypoints": len(m.waypoints),
                "faults": dict(m.faults),
                "timing": {
                    **executor.motor_timing(m.index),
                    "microsteps": m.params.microsteps,
                    "max_lag_full_steps": m.params.max_lag_full_steps,
                },
                "soft_stops": {
                    "count": m.soft_stops,
                    "takeover_ms": [round(t * 1000, 3) for t in m.takeover_s],
                    "takeover_steps": list(m.takeover_steps),
                },
            }
            for m in list(self.engine.motors)
        ]
        now = self.engine.clock.now()
        for doc, m in zip(motors, self.engine.motors, strict=True):
            doc["speed"] = motor_speed(m.traj, executor.motor_time(m.index, now))
        health = executor.health()
        steps = dict(health.latency)
        steps.update(health.counters)
        stats = executor.step_lateness()
        if histogram and stats is not None:  # the step executor's, with or without ramps
            steps["histogram_us"] = stats.histogram()
        out: dict[str, Any] = {
            "version": __version__,
            "motors": motors,
            "steps": steps,
            "executor": {
                "alive": health.alive,
                "reason": health.reason,
                "kind": step_executor_kind(self.config, executor),
                "core": executor.step_core(),
                "pid": getattr(executor, "pid", None),
            },
            "clamped": dict(self.dispatcher.clamped),
            "hard_stops": self.engine.stop_wait_status(),
            "state": self.persistence.status(),
            "pins": pin_status(self.hw.pins),
            "dc": dc_status(self.engine.dc, now),
        }
        mono = time.monotonic()
        out.update(
            monotonic_s=mono, uptime_s=round(mono - self.started, 3), unix_s=round(time.time(), 3)
        )
        if self.link is not None:
            out["link"] = self.link.status()
        if self.trace is not None:
            out["trace"] = self.trace.status()
        drivers = [d for s in self.hw.steppers if (d := s.driver.stats()) is not None]
        if drivers:  # SPI driver chips: polls, SPI status flag counts, faults, warnings
            out["drivers"] = drivers
        return out


def motor_speed(traj: Trajectory | None, now: float) -> float:
    """The planned speed at ``now`` in step/s, signed (0 without a trajectory)."""
    return 0.0 if traj is None else round(traj.velocity(now), 1)


def pin_status(pins: dict[int, Pin]) -> list[dict[str, Any]]:
    """Each IO pin: number, output or not, level (an input is read now; None if that
    failed, ``error`` says why)."""
    out: list[dict[str, Any]] = []
    for number, pin in sorted(pins.items()):
        entry: dict[str, Any] = {"number": number, "output": pin.is_output}
        try:
            entry["level"] = pin.read()
        except (HalError, OSError) as exc:
            entry.update(level=None, error=str(exc))
        out.append(entry)
    return out


def dc_status(dc: DcMotor | None, now: float) -> dict[str, Any] | None:
    """The DC motor's bridge state and the time left of its run; None: no DC motor."""
    if dc is None:
        return None
    deadline = dc.deadline
    return {
        "state": dc.bridge.state.value,
        "running": deadline is not None,
        "left_s": None if deadline is None else round(max(0.0, deadline - now), 3),
    }


def state_files_dir(config: Config, state_dir: Path) -> Path:
    """Where state.json lives: [state] directory, else the --state-dir (docs/service.md)."""
    return Path(config.state.directory) if config.state.directory else state_dir


def make_state_dir(state_dir: Path) -> None:
    try:
        state_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StartupError(
            f"cannot create state directory {state_dir}: {exc.strerror}; "
            "pass --state-dir with a writable directory"
        ) from exc
    if not os.access(state_dir, os.W_OK):
        raise StartupError(f"state directory {state_dir} is not writable; pass --state-dir")


def step_executor_kind(config: Config, executor: Executor) -> str:
    """``[step_thread] executor``, or "none" on a machine whose every motor runs on its
    TMC5160's own ramp (no step executor at all)."""
    return "none" if isinstance(executor, RampExecutor) else config.step_thread.executor


def build_executor(
    config: Config,
    hw: Hardware,
    spec: HardwareSpec,
    params: list[MotorParams],
    process: ExecutorProcess | None = None,
) -> Executor:
    """The step executor the config asks for (only it runs real-time and locks memory), for
    the motors ``spec.stepped()`` names; the motors whose driver runs its own ramp (the
    HAL's RampDriver: a TMC5160 with ``[motors.tmc] mode = "ramp"``) go to a RampExecutor
    instead and are not the step executor's at all (no STEP/DIR, no slot). Without stepped
    motors there is no step executor (nothing to run in real time). ``process``: an
    executor process started early (daemon/launch.py), the process executor's; ended here
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
            max_error_s=STEP_ERROR_S,
            spin_s=st.spin_us / 1e6,
            late_threshold_s=st.late_threshold_us / 1e6,
            rt=rt,
        )
        log.info("step core: python (the thread executor runs the Python core)")
    if process is not None:
        process.dismiss()  # no process executor after all (a no-op when it took it)
    return with_ramp_motors(steps, drivers, hw.clock)  # polled as the ramp drivers ask


def silence_watch(config: Config, dispatcher: Dispatcher, now: float) -> SilenceWatch:
    """``[link] timeout_ms`` and ``timeout_action``: the host's silence stops the motors
    (its silence counted from ``now``, on the link's clock)."""
    c = config.link
    hard = c.timeout_action == "hard"
    reason = f"link timeout: no byte from the host for {c.timeout_ms:g} ms"

    def act(now: float) -> list[str]:
        return dispatcher.link_silent(hard=hard, reason=reason)

    if c.timeout_ms > 0:
        log.info(
            "[link] timeout_ms = %g: the host's silence stops the motors in motion (%s)",
            c.timeout_ms,
            c.timeout_action,
        )
    return SilenceWatch(c.timeout_ms / 1000.0, act, now, c.timeout_action)


def open_trace(option: Path | None, config: Config, where: str) -> TraceRecorder | None:
    """The link's trace recorder, when ``--trace`` or ``[trace] file`` asks for one."""
    t = config.trace
    path = option.absolute() if option is not None else Path(t.file) if t.file else None
    if path is None:
        return None
    c = config.link
    info = CaptureInfo(
        role="daemon",
        checksum=c.checksum,
        crc_covers_ack=c.crc_covers_ack,
        strict_padding=c.strict_padding,
        frame_gap_ms=c.frame_gap_ms,
        port=where,
        application=f"motorctld {__version__}",
    )
    recorder = TraceRecorder(
        path, info, max(4096, int(t.max_file_mb * (1 << 20))), t.files, time.monotonic()
    )
    try:
        recorder.open()
    except OSError as exc:
        raise StartupError(
            f"cannot write the trace file {path}: {exc.strerror or exc}; "
            "give --trace (or [trace] file) a writable path"
        ) from exc
    log.info("tracing the link to %s (%d files of %.3g MiB at most)", path, t.files, t.max_file_mb)
    return recorder


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
