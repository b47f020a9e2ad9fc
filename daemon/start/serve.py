"""Running the daemon: from a config and the command line's say to an exit status.

:func:`serve` prepares the process (the interpreter's switch interval, the CPUs other than
the step thread's), locks the state directory and the PTY path (one daemon each,
daemon/instance.py), has the assembler build everything the daemon runs
(:func:`motorctl.daemon.start.assemble.build_served`, which closes what it opened when a part
fails), then runs it (:func:`run`): starts its threads, says READY, serves the link until a
stop signal (daemon/start/signals.py) or the step executor's death, shuts down (:func:`shutdown`:
motors ramp down, outputs safe, state written), closes, and says why it stopped in the exit
status (:func:`exit_status`).

Threads: the main thread runs all of it, and the link loop (``Link.serve``) while serving;
it starts ``motorctl-exec-death`` (:func:`stop_when_executor_dies`), which only waits and
stops the link; the threads of what it runs say at their own tops what they own.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from motorctl.daemon.config import Config, load_config
from motorctl.daemon.errors import StartupError
from motorctl.daemon.instance import LOCK_NAME, InstanceError, Owned
from motorctl.daemon.service import notify_backend, sd_notify
from motorctl.daemon.start.assemble import (
    Daemon,
    Served,
    ServeOptions,
    build_served,
    make_state_dir,
    state_dir_option,
    state_files_dir,
)
from motorctl.daemon.start.signals import StopSignals
from motorctl.daemon.start.timeline import StartTimeline
from motorctl.hal.interfaces import HalError
from motorctl.motion.engine import MotionEngine
from motorctl.motion.executors.process.start import WaitingInterpreter

if TYPE_CHECKING:
    from motorctl.dataclass_code import CodeCache

log = logging.getLogger("motorctl")

SHUTDOWN_LIMIT_S = 10.0

#: exit code when the step executor died; answers go on this long before that
EXIT_EXECUTOR_DIED = 3
EXECUTOR_DEATH_GRACE_S = 2.0

#: exit code when the final state could not be written at shutdown (e.g. a read-only or full
#: state directory): the state file keeps what was last written
EXIT_STATE_NOT_SAVED = 4


def serve(
    config_path: str | None,
    options: ServeOptions,
    executor_process: WaitingInterpreter | None = None,
    timeline: StartTimeline | None = None,
    dataclass_code: CodeCache | None = None,
) -> int:
    """Serve until stopped; the exit status. ConfigError or StartupError when the daemon
    cannot start (the message says what to fix). ``timeline``: the start's steps, marked
    as they end and logged at READY (daemon/start/timeline.py). ``dataclass_code``: the
    compiled dataclass methods the daemon was imported with (motorctl/dataclass_code.py),
    used for the config's declarations too (the config step imports the HAL's), and what
    it gave logged at debug level then."""
    timeline = timeline or StartTimeline("serve")
    with contextlib.nullcontext() if dataclass_code is None else dataclass_code.use():
        config = load_config(config_path)
    timeline.mark("config")
    if dataclass_code is not None:
        dataclass_code.release()  # the start's imports are done
        # a file found bad when loaded was told already (main.py); one found bad in use not
        report = log.warning if dataclass_code.failed_in_use else log.debug
        report("dataclass code: %s", dataclass_code.summary())
    stop = StopSignals()  # SIGTERM, SIGINT and SIGHUP: a clean shutdown, from now on
    with contextlib.ExitStack() as cleanup:
        owned = Owned()
        cleanup.callback(owned.cleanup)
        prepare_process(config)
        claim(config, options, owned)
        timeline.mark("locks")
        served = build_served(config, options, owned, executor_process, timeline)
        return run(served, stop, timeline)


def prepare_process(config: Config) -> None:
    """The config's notices logged; the interpreter's switch interval; every thread but the
    step thread kept off the step thread's CPU (``[step_thread]``)."""
    st = config.step_thread
    for notice in config.notices:
        log.warning("%s", notice)
    sys.setswitchinterval(st.switch_interval_us / 1e6)
    if st.cpu >= 0:
        others = os.sched_getaffinity(0) - {st.cpu}
        if others:  # every thread but the step thread keeps off its CPU
            os.sched_setaffinity(0, others)


def claim(config: Config, options: ServeOptions, owned: Owned) -> None:
    """One daemon per state directory and PTY path, before any file is touched: their
    locks, taken into ``owned``. StartupError naming the other daemon."""
    make_state_dir(options.state_dir)
    try:
        owned.lock(options.state_dir / LOCK_NAME, f"state directory {options.state_dir}")
        files_dir = state_files_dir(config, options.state_dir)
        if files_dir != options.state_dir:
            make_state_dir(files_dir, state_dir_option(config, options.state_dir))
            # the same folder by another name (relative, with '..', through a link): its
            # lock is held already, by this daemon; a second flock would refuse it
            if not same_folder(files_dir, options.state_dir):
                owned.lock(files_dir / LOCK_NAME, f"state directory {files_dir}")
        if options.pty is not None:
            pty = options.pty
            owned.lock(pty.with_name(f".{pty.name}.lock"), f"PTY {pty}")
    except InstanceError as exc:
        raise StartupError(str(exc)) from exc


def same_folder(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are the one folder (False when either cannot be looked at)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def run(served: Served, stop: StopSignals, timeline: StartTimeline | None = None) -> int:
    """Start what ``served`` runs, serve until a stop signal or the executor's death, then
    shut down and close; the exit status."""
    timeline = timeline or StartTimeline("run")
    daemon, link = served.daemon, served.link
    config = daemon.config
    try:  # first: a core that cannot run ([step_thread] core) is a start error, state untouched
        daemon.engine.executor.start()
    except HalError as exc:
        daemon.engine.executor.close()
        served.close()
        raise StartupError(str(exc)) from exc
    timeline.mark("executor ready")
    stop.attach(link.stop, link.signal_fd)
    daemon.persistence.start()
    daemon.engine.start()
    served.status.start()
    if served.watchdog is not None:
        served.watchdog.start()
    executor = daemon.engine.executor
    realtime, core = executor.realtime(), executor.step_core()
    if realtime is not None:
        words = realtime.words()
    else:
        words = "real time not reported" if core else "real time none (no step executor)"
    timeline.mark("threads")
    print(
        f"motorctld ready: serving {served.where}; config {config.source}; "
        f"{len(config.motors)} motors; {config.hal.backend} hardware; "
        f"step core {core or 'none'}; state in {daemon.state_dir}; {words}",
        flush=True,
    )
    if os.environ.get("NOTIFY_SOCKET"):
        log.info("systemd notifications through %s", notify_backend()[0])
    sd_notify("READY=1")
    log.debug("%s", timeline.text())
    # the start's garbage collected, what lives on frozen (rt.GcPolicy): a full collection,
    # which READY need not wait for; the link serves once it is done
    daemon.gc_policy.ready()
    served.line.start()
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
        served.line.stop("stopping: motors ramping down, state being written")
        saved = shutdown(daemon)
        served.close()
    return exit_status(daemon, saved)


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


def exit_status(daemon: Daemon, saved: bool) -> int:
    """Why the daemon stopped, logged, as its exit status: EXIT_EXECUTOR_DIED, then
    EXIT_STATE_NOT_SAVED (``saved``: whether the final state is durable), else 0."""
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
