"""motorctld: serve the motor-controller protocol on a PTY or a UART.

The command line only: its options (:func:`parse_args`), the commands that print and exit
(``--check-config``, ``--print-default-config``, ``--probe``, ``--status``), and serving:
lock the state directory and port, assemble the daemon (daemon/assemble.py), open the port
(daemon/ports.py), serve until a stop signal (daemon/signals.py) or the executor's death,
then shut down (motors ramp down, state written) and say why it stopped in the exit status.

Threads: the main thread runs all of it, and the link loop (``Link.serve``) while serving;
it starts ``motorctl-exec-death`` (:func:`stop_when_executor_dies`), which only waits and
stops the link.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType

from motorctl import __version__
from motorctl.daemon import platform_check
from motorctl.daemon.assemble import (
    Daemon,
    StartupError,
    hardware_spec,
    known_microsteps,
    make_state_dir,
    open_trace,
    progress_watch,
    silence_watch,
    state_files_dir,
)
from motorctl.daemon.config import Config, ConfigError, StepThreadConfig, load_config
from motorctl.daemon.devwatch import NOT_BACK, PathWatch
from motorctl.daemon.instance import LOCK_NAME, InstanceError, Owned
from motorctl.daemon.link import Link
from motorctl.daemon.ports import PtySlave, open_pty
from motorctl.daemon.serialport import DeviceError, SerialDevice
from motorctl.daemon.service import (
    MotorEventLog,
    StatusLine,
    Watchdog,
    notify_backend,
    sd_notify,
    setup_logging,
    watchdog_interval,
)
from motorctl.daemon.signals import StopSignals
from motorctl.daemon.silence import check_timeout
from motorctl.daemon.status import StatusServer, read_status, summary_line
from motorctl.hal.interfaces import MonotonicClock, ProbeReport
from motorctl.hal.registry import motors_lose_steps, probe_hardware
from motorctl.motion import compiled_core
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executor_process_start import ExecutorProcess
from motorctl.motion.motor import Motor

log = logging.getLogger("motorctl")

SHUTDOWN_LIMIT_S = 10.0

#: exit code when the step executor died; answers go on this long before that
EXIT_EXECUTOR_DIED = 3
EXECUTOR_DEATH_GRACE_S = 2.0

#: exit code when the final state could not be written at shutdown (e.g. a read-only or full
#: state directory): the state file keeps what was last written
EXIT_STATE_NOT_SAVED = 4


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
    where.add_argument(
        "--pty",
        metavar="PATH",
        type=Path,
        help="serve on a new pseudo-terminal; PATH becomes a symlink to it",
    )
    where.add_argument(
        "--port",
        metavar="DEVICE",
        help="serve on a real UART, e.g. /dev/ttyAMA0 or a USB adapter's "
        "/dev/serial/by-id/usb-... name; a device not there yet at start is served "
        "as soon as it appears, one that goes away is opened again by this path "
        "when it is back (state kept); one that is there but cannot be used (not a "
        "tty, no permission, busy) stops the start",
    )
    p.add_argument(
        "--baud",
        type=int,
        default=115200,
        help="UART baud rate (default 115200); [link] timeout_ms must be at least one "
        "frame's time at it (also checked by --check-config)",
    )
    p.add_argument(
        "--config",
        metavar="FILE",
        help="TOML config (default: the embedded mock world, see docs/config.md)",
    )
    p.add_argument("--check-config", metavar="FILE", help="check FILE and exit")
    p.add_argument(
        "--print-default-config",
        action="store_true",
        help="print the embedded default config, every key written out and commented, and exit",
    )
    p.add_argument(
        "--probe",
        action="store_true",
        help="open every line and device the --config names, without moving "
        "anything; print chips, lines and their current consumers, end-stop levels "
        "and driver status; exit 1 if something is missing or busy. Then check "
        "the platform: preemption model, RT throttling, cpufreq governor, "
        "isolated CPUs, under-voltage, a short latency measurement, and advice",
    )
    p.add_argument(
        "--latency-seconds",
        metavar="S",
        type=float,
        default=3.0,
        help="with --probe: how long to measure timer wake-ups at the executor's "
        "priority and CPU (default 3; 0: skip)",
    )
    p.add_argument(
        "--trace",
        metavar="FILE",
        type=Path,
        help="record every byte run on the link, timestamped, to FILE (pcapng, "
        "rotated as [trace] says; read it with 'motorctl trace FILE'; "
        "docs/trace.md); overrides [trace] file",
    )
    p.add_argument(
        "--state-dir",
        type=Path,
        default=Path("/run/motorctl"),
        help="the runtime directory: lock, status socket and, unless [state] "
        "directory says otherwise, the state file (default /run/motorctl)",
    )
    p.add_argument(
        "--status",
        action="store_true",
        help="print the running daemon's status (JSON) from --state-dir and exit",
    )
    p.add_argument(
        "--histogram",
        action="store_true",
        help="with --status: include the step edges' whole lateness histogram "
        "(steps.histogram_us: microseconds late -> steps)",
    )
    p.add_argument(
        "--format",
        choices=["json", "prometheus", "openmetrics"],
        default="json",
        help="with --status: json (the document, docs/status.md), prometheus (the "
        "Prometheus text format 0.0.4, names motorctl_*: what node_exporter's textfile "
        "collector reads) or openmetrics (the same metrics as OpenMetrics, for scrapers "
        "that ask for it); both need python3-prometheus-client; motorctl_up 0 and exit 1 "
        "when no daemon answers",
    )
    p.add_argument(
        "--watch",
        action="store_true",
        help="with --status: a live view that refreshes in the terminal "
        "(needs python3-rich; the same as 'motorctl monitor')",
    )
    p.add_argument(
        "--period",
        metavar="MS",
        type=int,
        default=250,
        help="with --status --watch: how often the daemon looks for a change "
        "(20..60000 ms, default 250)",
    )
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None, executor_process: ExecutorProcess | None = None) -> int:
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
        why = check_timeout(cfg.link.timeout_ms, args.baud)
        if why is not None:
            print(f"error: {args.check_config}: {why}", file=sys.stderr)
            return 1
        for notice in cfg.notices:
            print(f"warning: {notice}", file=sys.stderr)
        print(
            f"{args.check_config}: OK ({len(cfg.motors)} motors, {len(cfg.pins)} pins, "
            f"{'a' if cfg.dc else 'no'} DC motor, backend {cfg.hal.backend})"
        )
        return 0
    if args.probe:
        return probe(args.config, args.latency_seconds)
    if args.status:
        return status_command(args)
    for given, name in (
        (args.histogram, "--histogram"),
        (args.watch, "--watch"),
        (args.format != "json", "--format"),
    ):
        if given:
            print(f"error: {name} goes with --status", file=sys.stderr)
            return 2
    if args.pty is None and args.port is None:
        print(
            "error: say where to serve: --pty PATH (a pseudo-terminal) or --port DEVICE",
            file=sys.stderr,
        )
        return 2
    log.debug("logging to %s", logs_to)
    try:
        return serve(args, executor_process)
    except (ConfigError, StartupError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


#: what ``--status --format prometheus|openmetrics`` says without prometheus_client (an
#: optional dependency, like rich for the monitor: daemon/metrics.py alone imports it)
METRICS_MISSING = (
    "the metrics formats need the Python package 'prometheus_client', which is not "
    "installed: 'apt install python3-prometheus-client' (Debian, Raspberry Pi OS) or "
    "'pip install motorctl[metrics]'; the daemon itself does not need it, and "
    "'motorctld --status' prints the same figures as JSON"
)


def status_command(args: argparse.Namespace) -> int:
    """``--status``: the running daemon's status once (JSON or OpenMetrics), or watched."""
    path = args.state_dir / "status.sock"
    if args.watch:
        if args.histogram or args.format != "json":
            print(
                "error: --watch shows the live view; --histogram and --format go with a "
                "single --status",
                file=sys.stderr,
            )
            return 2
        from motorctl.daemon import monitor

        return monitor.run(path, args.period)
    if args.histogram and args.format != "json":
        print("error: --histogram goes with --format json", file=sys.stderr)
        return 2
    import json

    metrics: ModuleType | None = None
    if args.format != "json":
        try:
            from motorctl.daemon import metrics
        except ModuleNotFoundError as exc:
            if exc.name is None or exc.name.split(".")[0] != "prometheus_client":
                raise
            print(f"error: {METRICS_MISSING}", file=sys.stderr)
            return 2
    try:
        doc = read_status(path, histogram=args.histogram)
        if set(doc) == {"error"}:
            raise ValueError(doc["error"])
    except (OSError, ValueError) as exc:
        print(f"error: no daemon status at {path}: {exc}", file=sys.stderr)
        if metrics is not None:
            sys.stdout.write(metrics.down(args.format))
        return 1
    if metrics is not None:
        sys.stdout.write(metrics.metrics(doc, args.format))
    else:
        print(json.dumps(doc, indent=1))
    return 0


def probe(
    config_path: str | None, latency_s: float = 3.0, roots: platform_check.Roots | None = None
) -> int:
    """``--probe``: what the configured hardware looks like, moving nothing; then the
    platform (docs/timing.md, "Checking a platform"), which advises and never fails it."""
    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    spec = hardware_spec(config)
    report = probe_hardware(config.hal.backend, spec, MonotonicClock())
    st = config.step_thread
    report.add("step core", step_core_probe(st, report))
    print(f"motorctld --probe: config {config.source}, backend {config.hal.backend}")
    sys.stdout.write(report.text())
    sys.stdout.flush()
    timing = platform_check.TimingConfig(
        cpu=st.cpu, priority=st.priority, spin_us=st.spin_us, executor=st.executor
    )
    loses = motors_lose_steps(config.hal.backend, spec)
    motors = [
        platform_check.MotorRate(
            m.name, m.max_speed, known_microsteps(m), m.start_speed, m.max_lag_full_steps, loses
        )
        for m in config.motors
    ]
    found = platform_check.read_platform(roots or platform_check.Roots())
    if latency_s > 0:
        print(f"measuring timer wake-ups for {latency_s:g} s ...", flush=True)
        latency = platform_check.measure_latency(latency_s, st.priority, st.cpu)
        skipped = None
    else:
        latency, skipped = None, "not measured (--latency-seconds 0)"
    sys.stdout.write(platform_check.report(found, latency, timing, motors, skipped))
    return 1 if report.problems else 0


def step_core_probe(st: StepThreadConfig, report: ProbeReport) -> list[str]:
    """``--probe``'s lines on the step core: what is built, what the backend's lines offer,
    which core the daemon would run (``[step_thread] core``); a core = "compiled" that
    could not run is one of the report's problems."""
    built = compiled_core.unavailable()
    lines = report.compiled_lines
    out = [
        f'[step_thread] core = "{st.core}", executor = "{st.executor}"',
        f"compiled core: {'built' if built is None else built}",
        f"lines for it: {lines if lines is not None else 'not known (the lines did not open)'}",
    ]
    if st.executor == "thread":
        runs = "python (the thread executor runs the Python core)"
        if st.core == "compiled":
            report.problems.append(
                '[step_thread] core = "compiled" runs in the process executor only'
            )
    elif st.core == "python":
        runs = "python (as asked)"
    elif built is None and lines is not None and not lines.startswith("none"):
        runs = "compiled"
    else:
        why = built or f"the backend's lines: {lines or 'not known'}"
        runs = f"python ({why})"
        if st.core == "compiled":
            runs = "none: motorctld would not start"
            report.problems.append(f'[step_thread] core = "compiled", but {why}')
    out.append(f"runs: {runs}")
    return out


def serve(args: argparse.Namespace, executor_process: ExecutorProcess | None = None) -> int:
    config = load_config(args.config)
    stop = StopSignals()  # SIGTERM, SIGINT and SIGHUP: a clean shutdown, from now on
    with contextlib.ExitStack() as cleanup:
        owned = Owned()
        cleanup.callback(owned.cleanup)
        return _serve(args, config, stop, owned, executor_process)


def _serve(
    args: argparse.Namespace,
    config: Config,
    stop: StopSignals,
    owned: Owned,
    executor_process: ExecutorProcess | None = None,
) -> int:
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
    why = check_timeout(config.link.timeout_ms, args.baud)
    if why is not None:
        raise ConfigError(f"{config.source}: {why}")
    # The serial device before the state: one that is there but cannot be used stops the
    # start before the state is restored and written again; one that is not there yet is
    # served when it appears (the link waits for it as for one that went away).
    uart: SerialDevice | None = None
    fd = -1
    if args.port is not None:
        uart = SerialDevice(args.port, args.baud)
        try:
            fd = uart.open()
        except DeviceError as exc:
            if exc.errno not in NOT_BACK:
                raise StartupError(str(exc)) from exc
    try:
        daemon = Daemon.build(config, args.state_dir, executor_process=executor_process)
    except BaseException:
        if uart is not None:
            uart.close()
        raise
    pty: PtySlave | None = None
    try:
        if args.pty is not None:
            fd, name = open_pty(args.pty)
            owned.symlink(args.pty, name)
            pty = PtySlave(fd, name)
            where = f"{args.pty} -> {name}"
        else:
            where = f"{args.port} at {args.baud} baud"
            if fd < 0:
                where += " (not there yet: served when it appears)"
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
        if uart is not None:
            uart.close()
        raise
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
    )
    daemon.link = link
    daemon.trace = recorder
    try:
        status = StatusServer(args.state_dir / "status.sock", daemon.status)
    except OSError as exc:
        if recorder is not None:
            recorder.close()
        daemon.engine.executor.close()
        daemon.hw.close()
        raise StartupError(
            f"cannot serve the status socket {args.state_dir / 'status.sock'}: "
            f"{exc.strerror or exc}"
        ) from exc
    events = MotorEventLog()
    line = StatusLine(lambda: summary_line(daemon.status()), before=events.flush)

    def on_motor_event(motor: Motor, event: str) -> None:  # step thread: no I/O
        events.record(
            motor.index,
            motor.params.name,
            event,
            motor.fault,
            motor.fault_cause,
            motor.position_lost,
        )
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
    print(
        f"motorctld ready: serving {where}; config {config.source}; "
        f"{len(config.motors)} motors; {config.hal.backend} hardware; "
        f"step core {daemon.engine.executor.step_core() or 'none'}; "
        f"state in {args.state_dir}",
        flush=True,
    )
    if os.environ.get("NOTIFY_SOCKET"):
        log.info("systemd notifications through %s", notify_backend()[0])
    sd_notify("READY=1")
    line.start()
    threading.Thread(
        target=stop_when_executor_dies,
        args=(daemon.engine, link.stop),
        name="motorctl-exec-death",
        daemon=True,
    ).start()
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
        log.error(
            "stopped because the step executor died (%s): exit %d for the service "
            "manager to restart motorctld; every motor must be homed again",
            died,
            EXIT_EXECUTOR_DIED,
        )
        return EXIT_EXECUTOR_DIED
    if not saved:
        writer = daemon.writer
        log.error(
            "stopped WITHOUT saving the final state (%s): %s keeps what was last "
            "written (%d writes, %d failed); exit %d",
            writer.last_error,
            writer.path,
            writer.writes,
            writer.errors,
            EXIT_STATE_NOT_SAVED,
            extra={"STATE_PATH": str(writer.path)},
        )
        return EXIT_STATE_NOT_SAVED
    log.info("stopped")
    return 0


def stop_when_executor_dies(engine: MotionEngine, stop: Callable[[], None]) -> None:
    """After the executor died (every motor already faulted, E4), keep answering for
    ``EXECUTOR_DEATH_GRACE_S`` so the host and ``--status`` see why, then stop the daemon
    (exit EXIT_EXECUTOR_DIED: systemd's Restart= brings it back with positions lost)."""
    pause = threading.Event()
    while engine.executor_died is None:
        pause.wait(0.1)
    log.error(
        "the step executor died: %s; stopping in %.0f s",
        engine.executor_died,
        EXECUTOR_DEATH_GRACE_S,
    )
    pause.wait(EXECUTOR_DEATH_GRACE_S)
    stop()


def shutdown(daemon: Daemon) -> bool:
    """Stop along the ramps (bounded), brake the DC motor, set safe outputs, write state;
    True when the final state is durable."""
    engine = daemon.engine
    engine.shutdown()
    deadline = time.monotonic() + SHUTDOWN_LIMIT_S
    while time.monotonic() < deadline:
        with engine.lock:
            # a dead executor confirms no stop and moves nothing: nothing to wait for
            if engine.executor_died is not None or not any(
                m.active or m.stopping for m in engine.motors
            ):
                break
        time.sleep(0.005)
    with engine.lock:
        now = engine.clock.now()
        for m in engine.motors:
            if m.active:
                log.warning(
                    "motor %d did not stop within %.0f s: hard stop", m.index, SHUTDOWN_LIMIT_S
                )
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
