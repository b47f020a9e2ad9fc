"""motorctld: serve the motor-controller protocol on a PTY or a UART."""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import signal
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from types import FrameType
from typing import Any

from motorctl import __version__
from motorctl.daemon import platform_check
from motorctl.daemon.config import Config, ConfigError, MotorConfig, load_config
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.instance import LOCK_NAME, InstanceError, Owned
from motorctl.daemon.link import Link, flush_pty_input
from motorctl.daemon.serialport import DeviceError, SerialDevice
from motorctl.daemon.service import (
    MotorEventLog,
    ProgressWatch,
    StatusLine,
    Watchdog,
    notify_backend,
    sd_notify,
    setup_logging,
    watchdog_interval,
)
from motorctl.daemon.silence import SilenceWatch
from motorctl.daemon.state import MotorIdentity, Persistence, StateWriter, geometry_fingerprint
from motorctl.daemon.status import StatusServer, read_status, summary_line
from motorctl.daemon.trace import TraceRecorder
from motorctl.hal.backends.mock.backend import MockHardware
from motorctl.hal.backends.mock.config import MockAxisConfig, MockConfig
from motorctl.hal.backends.tmc.config import SpidevConfig, TmcAxisConfig, driver_spec
from motorctl.hal.backends.tmc.driver import TmcDriver
from motorctl.hal.backends.tmc.ramp import Tmc5160
from motorctl.hal.interfaces import Clock, HalError, Hardware, MonotonicClock, Pin
from motorctl.hal.registry import open_hardware, probe_hardware
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

SHUTDOWN_LIMIT_S = 10.0
#: exit code when the step executor died; answers go on this long before that
EXIT_EXECUTOR_DIED = 3
EXECUTOR_DEATH_GRACE_S = 2.0
#: exit code when the final state could not be written at shutdown (e.g. a read-only or full
#: state directory): the state file keeps what was last written
EXIT_STATE_NOT_SAVED = 4
#: the planner's step-time error bound (segments' reproduction of exact step times)
STEP_ERROR_S = 5e-6


class StartupError(Exception):
    """Something the user must fix before the daemon can start; the message says what."""


def hardware_spec(config: Config) -> HardwareSpec:
    """What the backend builds; every backend's config sections travel along (`sections`)."""
    st = config.step_thread
    axes = tuple(
        AxisSpec(
            invert_dir=m.invert_dir,
            endstop_active_low=m.endstop.active_low,
            endstop_min=m.section(MockAxisConfig).endstop_min,
            endstop_max=m.section(MockAxisConfig).endstop_max,
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
    wires = config.section(MockConfig).wires
    return HardwareSpec(
        axes, pins, dc=config.dc is not None, wires=wires, sections=config.sections
    )


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
    """Microsteps per full step: its own key, else its [motors.tmc] table's, else 16."""
    if m.microsteps is not None:
        return m.microsteps
    tmc = m.section(TmcAxisConfig)
    return tmc.microsteps if isinstance(tmc, TmcAxisConfig) else 16


def motor_geometry(config: Config, m: MotorConfig) -> dict[str, object]:
    """What gives a motor's saved positions their meaning: a change restores nothing."""
    tmc = m.section(TmcAxisConfig)
    return {"steps_per_rev": m.steps_per_rev, "invert_dir": m.invert_dir,
            "backend": config.hal.backend,
            "microsteps": tmc.microsteps if isinstance(tmc, TmcAxisConfig) else None}


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


def mock_extra(hw: Hardware) -> tuple[Callable[[], dict[str, Any]],
                                      Callable[[dict[str, Any]], None]] | None:
    """The mock world's axis positions live and die with the state file."""
    world = hw.world if isinstance(hw, MockHardware) else None
    if world is None:
        return None

    def get() -> dict[str, Any]:
        return {"mock": world.snapshot()}

    def put(extra: dict[str, Any]) -> None:
        mock = extra.get("mock")
        if isinstance(mock, dict):
            world.restore(mock)

    return get, put


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
    def build(cls, config: Config, state_dir: Path, clock: Clock | None = None,
              executor_process: ExecutorProcess | None = None) -> Daemon:
        """Everything behind the serial port; ``executor_process``: see :func:`main`."""
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
                hw, params, executor, driver_poll_s=config.step_thread.driver_poll_ms / 1000.0,
                stop_confirm_s=config.step_thread.stop_confirm_ms / 1000.0,
            )
            files_dir = state_files_dir(config, state_dir)
            make_state_dir(files_dir)
            persistence = Persistence(files_dir, motor_identities(config), engine,
                                      mock_extra(hw))
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
            {"index": m.index, "name": m.params.name, "state": m.state.value,
             "position": m.position, "queued": len(m.queue), "fault": m.fault,
             "position_lost": m.position_lost, "waypoints": len(m.waypoints),
             "faults": dict(m.faults),
             "timing": {**executor.motor_timing(m.index),
                        "microsteps": m.params.microsteps,
                        "max_lag_full_steps": m.params.max_lag_full_steps},
             "soft_stops": {"count": m.soft_stops,
                            "takeover_ms": [round(t * 1000, 3) for t in m.takeover_s],
                            "takeover_steps": list(m.takeover_steps)}}
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
        out: dict[str, Any] = {"motors": motors, "steps": steps,
                               "executor": {"alive": health.alive, "reason": health.reason,
                                            "kind": step_executor_kind(self.config,
                                                                       executor),
                                            "pid": getattr(executor, "pid", None)},
                               "clamped": dict(self.dispatcher.clamped),
                               "hard_stops": self.engine.stop_wait_status(),
                               "state": self.persistence.status(),
                               "pins": pin_status(self.hw.pins),
                               "dc": dc_status(self.engine.dc, now)}
        mono = time.monotonic()
        out.update(monotonic_s=mono, uptime_s=round(mono - self.started, 3),
                   unix_s=round(time.time(), 3))
        if self.link is not None:
            out["link"] = self.link.status()
        if self.trace is not None:
            out["trace"] = self.trace.status()
        drivers = [s.driver.stats() for s in self.hw.steppers if isinstance(s.driver, TmcDriver)]
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
    return {"state": dc.bridge.state.value, "running": deadline is not None,
            "left_s": None if deadline is None else round(max(0.0, deadline - now), 3)}


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


class StopSignals:
    """SIGTERM, SIGINT and SIGHUP all stop the daemon cleanly (docs/service.md says why).

    Installed first thing (main thread), so a signal during start-up is not lost: it is
    remembered and the daemon stops as soon as it could serve.

    Python runs a signal's handler in the main thread between bytecodes only: a signal that
    arrives just before the link loop's ``poll()`` (or is taken by another thread) would
    wait for the next byte from the host, for ever on an idle, open port. :meth:`attach`
    therefore also makes the link's wake-up pipe the signal wake-up descriptor
    (``signal.set_wakeup_fd``): the signal itself ends that ``poll()``. :meth:`detach`
    undoes it before the pipe is closed; later signals are only logged.
    """

    SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)

    def __init__(self) -> None:
        self.requested: str | None = None
        self._stop: Callable[[], None] | None = None
        self._wakeup: int | None = None  # the descriptor it replaced, while attached
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}

    def attach(self, stop: Callable[[], None], wakeup_fd: int | None = None) -> None:
        """Call ``stop`` on a signal (at once if one came already); ``wakeup_fd``: a
        non-blocking descriptor the signal itself writes a byte to (main thread only)."""
        self._stop = stop
        if wakeup_fd is not None:
            old = signal.set_wakeup_fd(wakeup_fd, warn_on_full_buffer=False)
            if self._wakeup is None:
                self._wakeup = old
        if self.requested is not None:
            stop()

    def detach(self) -> None:
        """Before the wake-up descriptor is closed: signals from now on are only logged."""
        self._stop = None
        if self._wakeup is not None:
            signal.set_wakeup_fd(self._wakeup)
            self._wakeup = None

    def restore(self) -> None:
        """Detach and give the signals back the handlers they had (tests in one process)."""
        self.detach()
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        again = self.requested is not None
        self.requested = name
        how = " (the terminal closed, or someone asked): stopping as for SIGTERM" \
            if signum == signal.SIGHUP else ": stopping"
        if again:
            how = ": already stopping"
        log.info("%s%s", name, how, extra={"SIGNAL": name})
        if self._stop is not None:
            self._stop()


def open_pty(path: Path) -> tuple[int, str]:
    """A new PTY in raw mode; ``path`` becomes a symlink to its slave. Returns the master fd
    and the slave's name.

    The daemon does not keep the slave open: the master then sees the host close the port
    (POLLHUP, EIO) and drops what was meant for it, as a UART's bytes to a closed port are
    lost, instead of leaving stale responses for the next host. The raw mode stays set while
    the master is open.

    The slave is mode 0660 with the daemon's group (the ``motorctl`` group under systemd):
    only that group's members may drive the motors."""
    if (path.exists() or path.is_symlink()) and not path.is_symlink():
        raise StartupError(f"{path} exists and is not a symlink; remove it or choose "
                           "another --pty path")
    master, slave = os.openpty()
    tty.setraw(slave, termios.TCSANOW)
    name = os.ttyname(slave)
    os.chown(name, -1, os.getegid())
    os.chmod(name, 0o660)
    os.close(slave)
    os.set_blocking(master, False)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        os.symlink(name, tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise StartupError(f"cannot create symlink {path}: {exc.strerror}") from exc
    return master, name


def open_uart(device: str, baud: int) -> tuple[SerialDevice, int]:
    """The UART (or any serial device) at ``device``, opened by that path so that it can be
    opened again by it when it goes away and comes back (daemon.serialport)."""
    uart = SerialDevice(device, baud)
    try:
        return uart, uart.open()
    except DeviceError as exc:
        raise StartupError(str(exc)) from exc


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="motorctld",
        description="Serve the motor-controller protocol (docs/protocol.md) on a PTY or a UART.",
        epilog="One daemon per --state-dir and --pty/--port: a second one exits naming the "
               "first's PID. SIGTERM, SIGINT and SIGHUP stop it cleanly (motors ramp down, "
               "state written, exit 0; exit 4 when the state could not be written). Under "
               "systemd it logs to the journal and reports READY/STATUS/STOPPING. See "
               "docs/service.md.",
    )
    p.add_argument("--version", action="version", version=f"motorctld {__version__}")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--pty", metavar="PATH", type=Path,
                       help="serve on a new pseudo-terminal; PATH becomes a symlink to it")
    where.add_argument("--port", metavar="DEVICE",
                       help="serve on a real UART, e.g. /dev/ttyAMA0 or a USB adapter's "
                       "/dev/serial/by-id/usb-... name; a device that goes away is opened "
                       "again by this path when it is back (state kept)")
    p.add_argument("--baud", type=int, default=115200, help="UART baud rate (default 115200)")
    p.add_argument("--config", metavar="FILE", help="TOML config (default: the embedded mock "
                   "world, see docs/config.md)")
    p.add_argument("--check-config", metavar="FILE", help="check FILE and exit")
    p.add_argument("--print-default-config", action="store_true",
                   help="print the embedded default config, every key written out and "
                   "commented, and exit")
    p.add_argument("--probe", action="store_true",
                   help="open every line and device the --config names, without moving "
                   "anything; print chips, lines and their current consumers, end-stop levels "
                   "and driver status; exit 1 if something is missing or busy. Then check "
                   "the platform: preemption model, RT throttling, cpufreq governor, "
                   "isolated CPUs, under-voltage, a short latency measurement, and advice")
    p.add_argument("--latency-seconds", metavar="S", type=float, default=3.0,
                   help="with --probe: how long to measure timer wake-ups at the executor's "
                   "priority and CPU (default 3; 0: skip)")
    p.add_argument("--trace", metavar="FILE", type=Path,
                   help="record every byte run on the link, timestamped, to FILE (pcapng, "
                   "rotated as [trace] says; read it with 'motorctl trace FILE'; "
                   "docs/trace.md); overrides [trace] file")
    p.add_argument("--state-dir", type=Path, default=Path("/run/motorctl"),
                   help="the runtime directory: lock, status socket and, unless [state] "
                   "directory says otherwise, the state file (default /run/motorctl)")
    p.add_argument("--status", action="store_true",
                   help="print the running daemon's status (JSON) from --state-dir and exit")
    p.add_argument("--histogram", action="store_true",
                   help="with --status: include the step edges' whole lateness histogram "
                   "(steps.histogram_us: microseconds late -> steps)")
    p.add_argument("--format", choices=["json", "openmetrics"], default="json",
                   help="with --status: json (the document, docs/status.md) or openmetrics "
                   "(the OpenMetrics text format, names motorctl_*, for node_exporter's "
                   "textfile collector; motorctl_up 0 and exit 1 when no daemon answers)")
    p.add_argument("--watch", action="store_true",
                   help="with --status: a live view that refreshes in the terminal "
                   "(needs python3-rich; the same as 'motorctl monitor')")
    p.add_argument("--period", metavar="MS", type=int, default=250,
                   help="with --status --watch: how often the daemon looks for a change "
                   "(20..60000 ms, default 250)")
    p.add_argument("--log-level", default="info",
                   choices=["debug", "info", "warning", "error"])
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None,
         executor_process: ExecutorProcess | None = None) -> int:
    """motorctld. ``executor_process``: the step executor's process, started before this
    module was imported (``daemon/launch.py``, the ``motorctld`` command): the process
    executor takes it over; ended unused otherwise (another executor, another command, an
    error)."""
    try:
        return _main(argv, executor_process)
    finally:
        if executor_process is not None:
            executor_process.dismiss()  # a no-op once taken over


def _main(argv: Sequence[str] | None, executor_process: ExecutorProcess | None) -> int:
    args = parse_args(argv)
    logs_to = setup_logging(args.log_level)
    if args.print_default_config:
        from motorctl.daemon.config import default_config_text

        sys.stdout.write(default_config_text())
        return 0
    if args.check_config:
        try:
            cfg = load_config(args.check_config)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        for notice in cfg.notices:
            print(f"warning: {notice}", file=sys.stderr)
        print(f"{args.check_config}: OK ({len(cfg.motors)} motors, {len(cfg.pins)} pins, "
              f"{'a' if cfg.dc else 'no'} DC motor, backend {cfg.hal.backend})")
        return 0
    if args.probe:
        return probe(args.config, args.latency_seconds)
    if args.status:
        return status_command(args)
    for given, name in ((args.histogram, "--histogram"), (args.watch, "--watch"),
                        (args.format != "json", "--format")):
        if given:
            print(f"error: {name} goes with --status", file=sys.stderr)
            return 2
    if args.pty is None and args.port is None:
        print("error: say where to serve: --pty PATH (a pseudo-terminal) or --port DEVICE",
              file=sys.stderr)
        return 2
    log.debug("logging to %s", logs_to)
    try:
        return serve(args, executor_process)
    except (ConfigError, StartupError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def status_command(args: argparse.Namespace) -> int:
    """``--status``: the running daemon's status once (JSON or OpenMetrics), or watched."""
    path = args.state_dir / "status.sock"
    if args.watch:
        if args.histogram or args.format != "json":
            print("error: --watch shows the live view; --histogram and --format go with a "
                  "single --status", file=sys.stderr)
            return 2
        from motorctl.daemon import monitor

        return monitor.run(path, args.period)
    if args.histogram and args.format != "json":
        print("error: --histogram goes with --format json", file=sys.stderr)
        return 2
    import json

    from motorctl.daemon import metrics

    try:
        doc = read_status(path, histogram=args.histogram)
        if set(doc) == {"error"}:
            raise ValueError(doc["error"])
    except (OSError, ValueError) as exc:
        print(f"error: no daemon status at {path}: {exc}", file=sys.stderr)
        if args.format == "openmetrics":
            sys.stdout.write(metrics.down(str(exc)))
        return 1
    if args.format == "openmetrics":
        sys.stdout.write(metrics.openmetrics(doc))
    else:
        print(json.dumps(doc, indent=1))
    return 0


def probe(config_path: str | None, latency_s: float = 3.0,
          roots: platform_check.Roots | None = None) -> int:
    """``--probe``: what the configured hardware looks like, moving nothing; then the
    platform (docs/timing.md, "Checking a platform"), which advises and never fails it."""
    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    report = probe_hardware(config.hal.backend, hardware_spec(config), MonotonicClock())
    print(f"motorctld --probe: config {config.source}, backend {config.hal.backend}")
    sys.stdout.write(report.text())
    sys.stdout.flush()
    st = config.step_thread
    timing = platform_check.TimingConfig(cpu=st.cpu, priority=st.priority, spin_us=st.spin_us,
                                         executor=st.executor)
    loses = config.hal.backend != "mock" or config.section(MockConfig).lose_steps
    motors = [platform_check.MotorRate(
        m.name, m.max_speed,
        motor_microsteps(m) if m.microsteps is not None or isinstance(
            m.section(TmcAxisConfig), TmcAxisConfig) else None,
        m.start_speed, m.max_lag_full_steps, loses) for m in config.motors]
    found = platform_check.read_platform(roots or platform_check.Roots())
    if latency_s > 0:
        print(f"measuring timer wake-ups for {latency_s:g} s ...", flush=True)
        latency = platform_check.measure_latency(latency_s, st.priority, st.cpu)
        skipped = None
    else:
        latency, skipped = None, "not measured (--latency-seconds 0)"
    sys.stdout.write(platform_check.report(found, latency, timing, motors, skipped))
    return 1 if report.problems else 0


def step_executor_kind(config: Config, executor: Executor) -> str:
    """``[step_thread] executor``, or "none" on a machine whose every motor runs on its
    TMC5160's own ramp (no step executor at all)."""
    return "none" if isinstance(executor, RampExecutor) else config.step_thread.executor


def build_executor(
    config: Config, hw: Hardware, spec: HardwareSpec, params: list[MotorParams],
    process: ExecutorProcess | None = None,
) -> Executor:
    """The step executor the config asks for (only it runs real-time and locks memory), for
    the motors ``spec.stepped()`` names; the motors whose TMC5160 runs its own ramp
    (``[motors.tmc] mode = "ramp"``) go to a RampExecutor instead and are not the step
    executor's at all (no STEP/DIR, no slot). Without stepped motors there is no step
    executor (nothing to run in real time). ``process``: an executor process started early
    (daemon/launch.py), the process executor's; ended here when the config has no use
    for it."""
    st = config.step_thread
    stepped = spec.stepped()
    drivers = [s.driver for s in hw.steppers]
    ramp = [i for i, d in enumerate(drivers) if isinstance(d, Tmc5160)]
    if set(ramp) | set(stepped) != set(range(len(drivers))) or set(ramp) & set(stepped):
        raise StartupError(f"ramp motors {ramp} and stepped motors {list(stepped)} disagree")
    limits = axis_limits([params[i] for i in stepped], STEP_ERROR_S,
                         slide_after_s=st.late_threshold_us / 1e6,
                         lag_faults=hw.motors_lose_steps)
    rt = RealtimeOptions(st.priority, st.lock_memory, st.cpu)
    steps: Executor | None = None
    if not stepped:
        pass
    elif hw.clock.is_virtual:  # tests drive a virtual clock themselves: the thread kind's job
        steps = ThreadStepExecutor(hw, config.hal.backend, spec, limits, max_error_s=0.0)
    elif st.executor == "process":
        steps = ProcessStepExecutor(
            hw, config.hal.backend, spec, limits, ahead_s=st.ahead_ms / 1000.0,
            max_error_s=STEP_ERROR_S, spin_s=st.spin_us / 1e6,
            late_threshold_s=st.late_threshold_us / 1e6, rt=rt, process=process,
        )
    else:
        steps = ThreadStepExecutor(
            hw, config.hal.backend, spec, limits, ahead_s=st.ahead_ms / 1000.0,
            max_error_s=STEP_ERROR_S, spin_s=st.spin_us / 1e6,
            late_threshold_s=st.late_threshold_us / 1e6, rt=rt,
        )
    if process is not None:
        process.dismiss()  # no process executor after all (a no-op when it took it)
    spi = config.section(SpidevConfig)
    return with_ramp_motors(steps, drivers, hw.clock, spi.ramp_poll_ms / 1000,
                            spi.ramp_idle_poll_ms / 1000)


def serve(args: argparse.Namespace, executor_process: ExecutorProcess | None = None) -> int:
    config = load_config(args.config)
    stop = StopSignals()  # SIGTERM, SIGINT and SIGHUP: a clean shutdown, from now on
    with contextlib.ExitStack() as cleanup:
        owned = Owned()
        cleanup.callback(owned.cleanup)
        return _serve(args, config, stop, owned, executor_process)


def _serve(args: argparse.Namespace, config: Config, stop: StopSignals, owned: Owned,
           executor_process: ExecutorProcess | None = None) -> int:
    st = config.step_thread
    for notice in config.notices:
        log.warning("%s", notice)
    sys.setswitchinterval(st.switch_interval_us / 1e6)
    if st.cpu >= 0:
        others = os.sched_getaffinity(0) - {st.cpu}
        if others:  # every thread but the step thread keeps off its CPU
            os.sched_setaffinity(0, others)
    make_state_dir(args.state_dir)
    try:  # one daemon per state directory and PTY path, before any file is touched
        owned.lock(args.state_dir / LOCK_NAME, f"state directory {args.state_dir}")
        files_dir = state_files_dir(config, args.state_dir)
        if files_dir != args.state_dir:
            make_state_dir(files_dir)
            owned.lock(files_dir / LOCK_NAME, f"state directory {files_dir}")
        if args.pty is not None:
            owned.lock(args.pty.with_name(f".{args.pty.name}.lock"), f"PTY {args.pty}")
    except InstanceError as exc:
        raise StartupError(str(exc)) from exc
    daemon = Daemon.build(config, args.state_dir, executor_process=executor_process)
    uart: SerialDevice | None = None
    try:
        if args.pty is not None:
            fd, name = open_pty(args.pty)
            owned.symlink(args.pty, name)
            where = f"{args.pty} -> {name}"
        else:
            uart, fd = open_uart(args.port, args.baud)
            where = f"{args.port} at {args.baud} baud"
    except BaseException:
        daemon.engine.executor.close()  # the process executor's shared memory
        daemon.hw.close()  # e.g. the mock's shared memory
        raise
    c = config.link
    try:
        recorder = open_trace(args.trace, config, where)
    except BaseException:
        daemon.engine.executor.close()
        daemon.hw.close()
        raise
    link = Link(fd, daemon.dispatcher, c.codec_options(), c.frame_gap_ms / 1000.0,
                c.held_frames, on_hangup=None if uart else partial(flush_pty_input, name),
                device=uart, watch=silence_watch(config, daemon.dispatcher, time.monotonic()),
                recorder=recorder)
    daemon.link = link
    daemon.trace = recorder
    status = StatusServer(args.state_dir / "status.sock", daemon.status)
    events = MotorEventLog()
    line = StatusLine(lambda: summary_line(daemon.status()), before=events.flush)

    def on_motor_event(motor: Motor, event: str) -> None:  # step thread: no I/O
        events.record(motor.index, motor.params.name, event, motor.fault, motor.fault_cause,
                      motor.position_lost)
        line.poke()
        status.poke()  # subscribers see a start, stop or fault at once

    daemon.engine.listeners.append(on_motor_event)
    daemon.writer.on_change = line.poke
    stop.attach(link.stop, link.signal_fd)
    daemon.persistence.start()
    daemon.engine.executor.start()
    daemon.engine.start()
    status.start()
    daemon.gc_policy.ready()
    interval = watchdog_interval()
    watchdog = None
    if interval:
        watch = progress_watch(daemon, link)
        watchdog = Watchdog(interval, watch.healthy)
        watchdog.start()
    print(f"motorctld ready: serving {where}; config {config.source}; "
          f"{len(config.motors)} motors; {config.hal.backend} hardware; "
          f"state in {args.state_dir}", flush=True)
    if os.environ.get("NOTIFY_SOCKET"):
        log.info("systemd notifications through %s", notify_backend()[0])
    sd_notify("READY=1")
    line.start()
    threading.Thread(target=stop_when_executor_dies, args=(daemon.engine, link.stop),
                     name="motorctl-exec-death", daemon=True).start()
    try:
        link.serve()  # returns at once when a signal came during start-up
    finally:
        stop.detach()  # before link.close() closes the wake-up pipe
        sd_notify("STOPPING=1")
        line.stop("stopping: motors ramping down, state being written")
        saved = shutdown(daemon)
        if watchdog is not None:
            watchdog.stop()
        status.close()
        link.close()
        if recorder is not None:
            recorder.close()
        if uart is not None:
            uart.close()
        else:
            os.close(fd)
        daemon.hw.close()
    died = daemon.engine.executor_died
    if died is not None:
        log.error("stopped because the step executor died (%s): exit %d for the service "
                  "manager to restart motorctld; every motor must be homed again", died,
                  EXIT_EXECUTOR_DIED)
        return EXIT_EXECUTOR_DIED
    if not saved:
        writer = daemon.writer
        log.error("stopped WITHOUT saving the final state (%s): %s keeps what was last "
                  "written (%d writes, %d failed); exit %d", writer.last_error, writer.path,
                  writer.writes, writer.errors, EXIT_STATE_NOT_SAVED,
                  extra={"STATE_PATH": str(writer.path)})
        return EXIT_STATE_NOT_SAVED
    log.info("stopped")
    return 0


def silence_watch(config: Config, dispatcher: Dispatcher, now: float) -> SilenceWatch:
    """``[link] timeout_ms`` and ``timeout_action``: the host's silence stops the motors
    (its silence counted from ``now``, on the link's clock)."""
    c = config.link
    hard = c.timeout_action == "hard"
    reason = f"link timeout: no byte from the host for {c.timeout_ms:g} ms"

    def act(now: float) -> list[str]:
        return dispatcher.link_silent(hard=hard, reason=reason)

    if c.timeout_ms > 0:
        log.info("[link] timeout_ms = %g: the host's silence stops the motors in motion (%s)",
                 c.timeout_ms, c.timeout_action)
    return SilenceWatch(c.timeout_ms / 1000.0, act, now, c.timeout_action)


def open_trace(option: Path | None, config: Config, where: str) -> TraceRecorder | None:
    """The link's trace recorder, when ``--trace`` or ``[trace] file`` asks for one."""
    t = config.trace
    path = option.absolute() if option is not None else Path(t.file) if t.file else None
    if path is None:
        return None
    c = config.link
    info = CaptureInfo(role="daemon", checksum=c.checksum, crc_covers_ack=c.crc_covers_ack,
                       strict_padding=c.strict_padding, frame_gap_ms=c.frame_gap_ms,
                       port=where, application=f"motorctld {__version__}")
    recorder = TraceRecorder(path, info, max(4096, int(t.max_file_mb * (1 << 20))), t.files,
                             time.monotonic())
    try:
        recorder.open()
    except OSError as exc:
        raise StartupError(f"cannot write the trace file {path}: {exc.strerror or exc}; "
                           "give --trace (or [trace] file) a writable path") from exc
    log.info("tracing the link to %s (%d files of %.3g MiB at most)", path, t.files,
             t.max_file_mb)
    return recorder


def stop_when_executor_dies(engine: MotionEngine, stop: Callable[[], None]) -> None:
    """After the executor died (every motor already faulted, E4), keep answering for
    ``EXECUTOR_DEATH_GRACE_S`` so the host and ``--status`` see why, then stop the daemon
    (exit EXIT_EXECUTOR_DIED: systemd's Restart= brings it back with positions lost)."""
    pause = threading.Event()
    while engine.executor_died is None:
        pause.wait(0.1)
    log.error("the step executor died: %s; stopping in %.0f s", engine.executor_died,
              EXECUTOR_DEATH_GRACE_S)
    pause.wait(EXECUTOR_DEATH_GRACE_S)
    stop()


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
        {"link loop": lambda: link.turns, "planner": planner, "step executor": executor,
         "state writer": state_writer},
        pokes=(link.poke,),
    )


def shutdown(daemon: Daemon) -> bool:
    """Stop along the ramps (bounded), brake the DC motor, set safe outputs, write state;
    True when the final state is durable."""
    engine = daemon.engine
    engine.shutdown()
    deadline = time.monotonic() + SHUTDOWN_LIMIT_S
    while time.monotonic() < deadline:
        with engine.lock:
            # a dead executor confirms no stop and moves nothing: nothing to wait for
            if engine.executor_died is not None or not any(m.active or m.stopping
                                                           for m in engine.motors):
                break
        time.sleep(0.005)
    with engine.lock:
        now = engine.clock.now()
        for m in engine.motors:
            if m.active:
                log.warning("motor %d did not stop within %.0f s: hard stop", m.index,
                            SHUTDOWN_LIMIT_S)
                m.stop(hard=True, now=now)
    engine.stop_threads()
    engine.executor.close()
    for p in daemon.config.pins:
        pin = daemon.hw.pins.get(p.number)
        if pin is not None and pin.is_output:
            pin.write(p.safe)
    saved = daemon.persistence.close()
    gc.enable()
    return saved


if __name__ == "__main__":
    raise SystemExit(main())
