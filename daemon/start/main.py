"""motorctld: serve the motor-controller protocol on a PTY or a UART.

The command line only: its options (:func:`parse_args`), the commands that print and exit
(``--check-config``, ``--print-default-config``, ``--probe`` with the platform check of
daemon/start/platform_check.py, ``--status`` read through daemon/status/reader.py), and, for a
command line that serves, the hand-over to daemon/start/serve.py, which runs the daemon; a
daemon that cannot start says why here, in one line, and exits 1.

What only a command that prints and exits needs (the platform check, the status reader and
its summary, the compiled core's probe) is imported when that command runs: a start that
serves imports none of it (tests/daemon/start/test_launch_startup.py).

Threads: the main thread, all of it (serving goes on in daemon/start/serve.py on this thread).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import stat
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

from motorctl import __version__
from motorctl.daemon.config import ConfigError, StepThreadConfig, load_config
from motorctl.daemon.config.model import names_a_folder
from motorctl.daemon.errors import StartupError
from motorctl.daemon.link.silence import check_timeout
from motorctl.daemon.service import setup_logging
from motorctl.daemon.start.assemble import ServeOptions, hardware_spec, known_microsteps
from motorctl.daemon.start.serve import serve
from motorctl.daemon.start.timeline import StartTimeline
from motorctl.daemon.state.files import BIND_SUFFIX, SOCKET_PATH_MAX
from motorctl.hal.contract import ProbeReport, ProblemKind
from motorctl.hal.interfaces import MonotonicClock
from motorctl.hal.registry import motors_lose_steps, probe_hardware
from motorctl.motion.executors.process.start import WaitingInterpreter
from motorctl.motion.rt import RealtimeOptions
from motorctl.protocol.line import parse_baud

if TYPE_CHECKING:
    from motorctl.daemon.start import platform_check
    from motorctl.dataclass_code import CodeCache

log = logging.getLogger("motorctl")


def terminal_columns() -> int:
    """The terminal's width as ``shutil.get_terminal_size`` finds it: ``COLUMNS``, else
    standard output's terminal, else 80."""
    try:
        columns = int(os.environ["COLUMNS"])
    except (KeyError, ValueError):
        columns = 0
    if columns > 0:
        return columns
    stdout = sys.__stdout__
    if stdout is None:
        return 80
    try:
        return os.get_terminal_size(stdout.fileno()).columns or 80
    except (ValueError, OSError):
        return 80


class HelpFormatter(argparse.HelpFormatter):
    """argparse's own, at the width it would choose (:func:`terminal_columns`, less 2),
    found without importing shutil: argparse makes a formatter for every option it is
    given, and shutil (with its archive modules) would be imported by every start for it."""

    def __init__(
        self,
        prog: str,
        indent_increment: int = 2,
        max_help_position: int = 24,
        width: int | None = None,
    ) -> None:
        width = terminal_columns() - 2 if width is None else width
        super().__init__(prog, indent_increment, max_help_position, width)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="motorctld",
        formatter_class=HelpFormatter,
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
        type=file_path,
        help="serve on a new pseudo-terminal; PATH becomes a symlink to it",
    )
    where.add_argument(
        "--port",
        metavar="DEVICE",
        type=some_path,
        help="serve on a real UART, e.g. /dev/ttyAMA0 or a USB adapter's "
        "/dev/serial/by-id/usb-... name; a device not there yet at start is served "
        "as soon as it appears, one that goes away is opened again by this path "
        "when it is back (state kept); one that is there but cannot be used (not a "
        "tty, no permission, busy) stops the start",
    )
    p.add_argument(
        "--baud",
        type=baud_rate,
        default=115200,
        help="UART baud rate (default 115200; any whole number of baud the UART's driver "
        "can make); [link] timeout_ms must be at least one frame's time at it (also "
        "checked by --check-config)",
    )
    p.add_argument(
        "--config",
        metavar="FILE",
        type=some_path,
        help="TOML config (default: the embedded mock world, see docs/config.md)",
    )
    p.add_argument("--check-config", metavar="FILE", type=some_path, help="check FILE and exit")
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
        type=latency_seconds,
        default=3.0,
        help="with --probe: how long to measure timer wake-ups at the executor's "
        "priority and CPU (default 3; 0: skip; at most 3600)",
    )
    p.add_argument(
        "--trace",
        metavar="FILE",
        type=file_path,
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
        help="print the running daemon's status from --state-dir and exit: on a terminal "
        "a summary (motors, faults, link, step timing, real time granted or refused), "
        "else (a pipe, a file) the whole document as JSON (docs/status.md)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="with --status: the whole document as JSON, on a terminal too",
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


EXIT_PIPE = 128 + 13  # as a program killed by SIGPIPE


def baud_rate(text: str) -> int:
    """argparse type: a baud rate (motorctl.protocol.line, the client's rule too)."""
    try:
        return parse_baud(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: the longest latency measurement ``--probe`` makes (an hour: longer is a mistake)
LATENCY_LIMIT_S = 3600.0


def latency_seconds(text: str) -> float:
    """argparse type: ``--latency-seconds``, 0 (skip) to LATENCY_LIMIT_S, a finite number
    (``inf`` would measure for ever, ``nan`` cannot be timed)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 <= value <= LATENCY_LIMIT_S:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number of seconds in 0..{LATENCY_LIMIT_S:g} (0 skips it)"
        )
    return value


def file_path(text: str) -> Path:
    """argparse type of ``--pty`` and ``--trace``: the path of a file the daemon makes. One
    written as a folder (``''``, ``.``, ``..``, a trailing ``/``: ``--trace /var/log/x/``)
    is refused, as ``[trace] file`` is (:func:`names_a_folder`)."""
    if names_a_folder(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} names a folder, not a file; give the path of the file to make in "
            "it (e.g. ./motorctl.pty, /tmp/link.pcapng)"
        )
    return Path(text)


def some_path(text: str) -> str:
    """argparse type of ``--port``, ``--config`` and ``--check-config``: a path, not an
    empty word (``--port ""`` waited for ever for a device of no name, ``--check-config ""``
    was taken for no option at all)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is no path; give one")
    return text


def state_dir_problem(state_dir: Path) -> str | None:
    """Why the status socket cannot be bound in ``--state-dir``: its path would be too long
    for a Unix socket (found before anything is made, not after the state was restored)."""
    size = len(os.fsencode(state_dir)) + BIND_SUFFIX
    if size <= SOCKET_PATH_MAX:
        return None
    return (
        f"--state-dir {state_dir}: too long for the status socket in it (a Unix socket's path "
        f"holds at most {SOCKET_PATH_MAX} bytes, {size} here); give a shorter path"
    )


def pty_folder_problem(pty: Path) -> str | None:
    """Why ``--pty PATH`` cannot be served: its folder (where the PTY's link and its lock
    go) is missing, not a folder, or not writable; None when it can be tried."""
    folder = Path(os.path.abspath(pty)).parent
    fix = f"create it ('mkdir -p {folder}') or give --pty a path in an existing folder"
    try:
        st = folder.stat()
    except FileNotFoundError:
        return f"--pty {pty}: the folder {folder} does not exist; {fix}"
    except OSError as exc:
        return f"--pty {pty}: cannot look at the folder {folder}: {exc.strerror}"
    if not stat.S_ISDIR(st.st_mode):
        return f"--pty {pty}: {folder} is not a folder; give --pty a path in a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return (
            f"--pty {pty}: the folder {folder} is not writable for this user (the PTY's "
            "link and its lock are made there); give --pty a path in a folder it may write"
        )
    return None


def main(
    argv: Sequence[str] | None = None,
    executor_process: WaitingInterpreter | None = None,
    dataclass_code: CodeCache | None = None,
) -> int:
    """motorctld. ``executor_process``: the step executor's process, started before this
    module was imported (``daemon/start/launch.py``, the ``motorctld`` command): the process
    executor takes it over; ended unused otherwise (another executor, another command, an
    error). ``dataclass_code``: the compiled dataclass methods the daemon's modules were
    imported with (the ``motorctld`` command too; motorctl/dataclass_code.py), logged once
    logging is set up: as a warning why it was not used; what it gave, at debug level once
    the config is read (daemon/start/serve.py, which uses it for the config too). Output
    into a pipe whose reader went away (``motorctld --status | head``) ends the command
    quietly, as it ends ``cat``, with the status of a program SIGPIPE ended."""
    timeline = StartTimeline("imported")  # a serving start's steps (daemon/start/timeline.py)
    try:
        code = _main(argv, executor_process, timeline, dataclass_code)
        sys.stdout.flush()  # here, not at exit: a reader gone is a broken pipe caught below
        return code
    except BrokenPipeError:
        # Python would flush stdout again at exit and complain: point it at /dev/null
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_PIPE
    finally:
        if executor_process is not None:
            executor_process.dismiss()  # a no-op once taken over


def _main(
    argv: Sequence[str] | None,
    executor_process: WaitingInterpreter | None,
    timeline: StartTimeline,
    dataclass_code: CodeCache | None = None,
) -> int:
    args = parse_args(argv)
    logs_to = setup_logging(args.log_level)
    if dataclass_code is not None and dataclass_code.problem is not None:
        log.warning("dataclass code: %s", dataclass_code.summary())
    timeline.mark("arguments")
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
        (args.json, "--json"),
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
    if args.pty is not None and (why := pty_folder_problem(args.pty)) is not None:
        print(f"error: {why}", file=sys.stderr)
        return 1
    if (why := state_dir_problem(args.state_dir)) is not None:
        print(f"error: {why}", file=sys.stderr)
        return 1
    log.debug("logging to %s", logs_to)
    options = ServeOptions(args.state_dir, args.pty, args.port, args.baud, args.trace)
    try:
        return serve(args.config, options, executor_process, timeline, dataclass_code)
    except (ConfigError, StartupError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


#: what ``--status --format prometheus|openmetrics`` says without prometheus_client (an
#: optional dependency, like rich for the monitor: daemon/status/metrics.py alone imports it)
METRICS_MISSING = (
    "the metrics formats need the Python package 'prometheus_client', which is not "
    "installed: 'apt install python3-prometheus-client' (Debian, Raspberry Pi OS) or "
    "'pip install motorctl[metrics]'; the daemon itself does not need it, and "
    "'motorctld --status' prints the same figures as JSON"
)


def status_command(args: argparse.Namespace) -> int:
    """``--status``: the running daemon's status once (on a terminal a summary, else the
    JSON document; or metrics), or watched."""
    path = args.state_dir / "status.sock"
    if args.watch:
        if args.histogram or args.json or args.format != "json":
            print(
                "error: --watch shows the live view; --histogram, --json and --format go "
                "with a single --status",
                file=sys.stderr,
            )
            return 2
        from motorctl.daemon.status import monitor

        return monitor.run(path, args.period)
    if args.histogram and args.format != "json":
        print("error: --histogram goes with --format json", file=sys.stderr)
        return 2
    import json

    from motorctl.daemon.status.reader import read_status, unreachable

    metrics: ModuleType | None = None
    if args.format != "json":
        try:
            from motorctl.daemon.status import metrics
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
        print(f"error: no daemon status at {path}: {unreachable(path, exc)}", file=sys.stderr)
        if metrics is not None:
            sys.stdout.write(metrics.down(args.format))
        return 1
    if metrics is not None:
        sys.stdout.write(metrics.metrics(doc, args.format))
    elif args.json or args.histogram or not sys.stdout.isatty():
        print(json.dumps(doc, indent=1))  # scripts and pipes: the document as it is
    else:
        import shutil

        from motorctl.daemon.status.summary import summary

        sys.stdout.write(summary(doc, min(shutil.get_terminal_size().columns, 120)))
    return 0


def probe(
    config_path: str | None, latency_s: float = 3.0, roots: platform_check.Roots | None = None
) -> int:
    """``--probe``: what the configured hardware looks like, moving nothing; then the
    platform (docs/timing.md, "Checking a platform"), which advises and never fails it."""
    from motorctl.daemon.start import platform_check

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
    rt = RealtimeOptions(st.priority, st.lock_memory, st.cpu)
    got, latency = platform_check.measure_latency(latency_s, rt)
    skipped = None if latency_s > 0 else "not measured (--latency-seconds 0)"
    sys.stdout.write(platform_check.report(found, latency, timing, motors, skipped, got))
    return 1 if report.problems else 0


def step_core_probe(st: StepThreadConfig, report: ProbeReport) -> list[str]:
    """``--probe``'s lines on the step core: what is built, what the backend's lines offer,
    which core the daemon would run (``[step_thread] core``); a core = "compiled" that
    could not run is one of the report's problems."""
    from motorctl.motion.executors import compiled_core

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
            report.problem(
                '[step_thread] core = "compiled" runs in the process executor only',
                ProblemKind.CONFIG,
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
            report.problem(f'[step_thread] core = "compiled", but {why}', ProblemKind.CONFIG)
    out.append(f"runs: {runs}")
    return out


if __name__ == "__main__":
    raise SystemExit(main())
