"""motorctld: serve the motor-controller protocol on a PTY or a UART."""

from __future__ import annotations

import argparse
import gc
import logging
import os
import signal
import sys
import termios
import time
import tty
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from types import FrameType
from typing import Any

from motorctl import __version__
from motorctl.daemon.config import Config, ConfigError, load_config
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.link import Link, flush_pty_input
from motorctl.daemon.service import Watchdog, sd_notify, watchdog_interval
from motorctl.daemon.state import StateError, StateWriter, read_state
from motorctl.daemon.status import StatusServer, read_status
from motorctl.hal.interfaces import Clock, HalError, Hardware, MonotonicClock
from motorctl.hal.mock import MockHardware
from motorctl.hal.mock_config import MockAxisConfig, MockConfig
from motorctl.hal.registry import open_hardware, probe_hardware
from motorctl.hal.spec import AxisSpec, HardwareSpec, PinSpec
from motorctl.motion.engine import MotionEngine
from motorctl.motion.motor import Motor
from motorctl.motion.stepthread import GcPolicy, StepThread, set_realtime
from motorctl.motion.types import HomingParams, MotorParams
from motorctl.protocol.codec import wrap24

log = logging.getLogger("motorctl")

SHUTDOWN_LIMIT_S = 10.0


class StartupError(Exception):
    """Something the user must fix before the daemon can start; the message says what."""


def hardware_spec(config: Config) -> HardwareSpec:
    """What the backend builds; every backend's config sections travel along (`sections`)."""
    axes = tuple(
        AxisSpec(
            invert_dir=m.invert_dir,
            endstop_active_low=m.endstop.active_low,
            endstop_min=m.section(MockAxisConfig).endstop_min,
            endstop_max=m.section(MockAxisConfig).endstop_max,
            debounce_s=m.endstop.debounce_ms / 1000.0,
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
            host_position=wrap24,
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
    writer: StateWriter
    gc_policy: GcPolicy = field(default_factory=GcPolicy)
    link: Link | None = None

    @classmethod
    def build(cls, config: Config, state_dir: Path, clock: Clock | None = None) -> Daemon:
        clock = clock or MonotonicClock()
        try:
            state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StartupError(
                f"cannot create state directory {state_dir}: {exc.strerror}; "
                "pass --state-dir with a writable directory"
            ) from exc
        if not os.access(state_dir, os.W_OK):
            raise StartupError(f"state directory {state_dir} is not writable; pass --state-dir")
        try:
            hw = open_hardware(config.hal.backend, hardware_spec(config), clock)
        except HalError as exc:
            raise StartupError(str(exc)) from exc
        engine = MotionEngine(
            hw,
            motor_params(config),
            endstop_active_low=[m.endstop.active_low for m in config.motors],
            driver_poll_s=config.step_thread.driver_poll_ms / 1000.0,
            late_threshold_s=config.step_thread.late_threshold_us / 1e6,
        )
        holder: list[Daemon] = []
        writer = StateWriter(state_dir / "state.json", lambda: holder[0].snapshot())
        dispatcher = Dispatcher(config, engine, hw.pins, on_saved=writer.request)
        daemon = cls(config, state_dir, clock, hw, engine, dispatcher, writer)
        holder.append(daemon)
        daemon.restore()
        engine.listeners.append(daemon._on_motor_event)
        return daemon

    # -- persistence -------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        with self.engine.lock:
            motors = [
                {
                    "name": m.params.name,
                    "position": m.position,
                    "home": m.home,
                    "waypoints": list(m.waypoints),
                    "moving": m.active or bool(m.queue),
                    "position_lost": m.position_lost,
                }
                for m in self.engine.motors
            ]
            data: dict[str, Any] = {"version": 1, "motors": motors}
            if isinstance(self.hw, MockHardware) and self.hw.world is not None:
                data["mock"] = self.hw.world.snapshot()
        return data

    def restore(self) -> None:
        path = self.writer.path
        try:
            data = read_state(path)
        except StateError as exc:
            bad = path.with_name(path.name + ".bad")
            os.replace(path, bad)
            log.error("%s; kept it as %s; every motor must be homed again", exc, bad)
            for m in self.engine.motors:
                m.position_lost = True
            return
        if data is None:
            return
        for m, saved in zip(self.engine.motors, data["motors"], strict=False):
            self._restore_motor(m, saved)
        if isinstance(self.hw, MockHardware) and self.hw.world is not None:
            mock = data.get("mock")
            if isinstance(mock, dict):
                self.hw.world.restore(mock)
        log.info("restored state from %s", path)

    @staticmethod
    def _restore_motor(m: Motor, saved: Any) -> None:
        if not isinstance(saved, dict):
            m.position_lost = True
            return
        pos, home, wps = saved.get("position"), saved.get("home"), saved.get("waypoints")
        if isinstance(pos, int):
            m.set_position(pos)
        if isinstance(home, int):
            m.home = home
        if isinstance(wps, list):
            m.waypoints = [w for w in wps if isinstance(w, int)][: m.params.max_waypoints]
        if saved.get("moving") or saved.get("position_lost") or not isinstance(pos, int):
            m.position_lost = True
            log.warning("motor %d (%s) was moving when the daemon stopped: position lost, "
                        "home it with InitMove", m.index, m.params.name)

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
    def status(self) -> dict[str, Any]:
        with self.engine.lock:
            motors = [
                {"index": m.index, "name": m.params.name, "state": m.state.value,
                 "position": m.position, "queued": len(m.queue), "fault": m.fault,
                 "position_lost": m.position_lost, "waypoints": len(m.waypoints)}
                for m in self.engine.motors
            ]
            steps = self.engine.stats.summary()
            steps["histogram_us"] = self.engine.stats.histogram()
        out: dict[str, Any] = {"motors": motors, "steps": steps,
                               "clamped": dict(self.dispatcher.clamped),
                               "state_writes": self.writer.writes}
        if self.link is not None:
            out["link"] = self.link.status()
        return out


def open_pty(path: Path) -> tuple[int, str]:
    """A new PTY in raw mode; ``path`` becomes a symlink to its slave. Returns the master fd
    and the slave's name.

    The daemon does not keep the slave open: the master then sees the host close the port
    (POLLHUP, EIO) and drops what was meant for it, as a UART's bytes to a closed port are
    lost, instead of leaving stale responses for the next host. The raw mode stays set while
    the master is open."""
    if (path.exists() or path.is_symlink()) and not path.is_symlink():
        raise StartupError(f"{path} exists and is not a symlink; remove it or choose "
                           "another --pty path")
    master, slave = os.openpty()
    tty.setraw(slave, termios.TCSANOW)
    name = os.ttyname(slave)
    os.chmod(name, 0o666)
    os.close(slave)
    os.set_blocking(master, False)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        os.symlink(name, tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise StartupError(f"cannot create symlink {path}: {exc.strerror}") from exc
    return master, name


def open_uart(device: str, baud: int) -> tuple[Any, int]:
    import serial

    try:
        port = serial.Serial(device, baud, timeout=0, exclusive=True)
    except serial.SerialException as exc:
        raise StartupError(
            f"cannot open serial device {device}: {exc}; check the path (ls -l /dev/serial* "
            "/dev/tty{AMA,S,USB}*), that the UART is enabled, and that the user is in the "
            "dialout group"
        ) from exc
    return port, port.fileno()


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="motorctld",
        description="Serve the motor-controller protocol (docs/protocol.md) on a PTY or a UART.",
    )
    p.add_argument("--version", action="version", version=f"motorctld {__version__}")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--pty", metavar="PATH", type=Path,
                       help="serve on a new pseudo-terminal; PATH becomes a symlink to it")
    where.add_argument("--port", metavar="DEVICE", help="serve on a real UART, e.g. /dev/ttyAMA0")
    p.add_argument("--baud", type=int, default=115200, help="UART baud rate (default 115200)")
    p.add_argument("--config", metavar="FILE", help="TOML config (default: the embedded mock "
                   "world, see docs/config.md)")
    p.add_argument("--check-config", metavar="FILE", help="check FILE and exit")
    p.add_argument("--print-default-config", action="store_true",
                   help="print the embedded default config and exit")
    p.add_argument("--probe", action="store_true",
                   help="open every line and device the --config names, without moving "
                   "anything; print chips, lines and their current consumers, end-stop levels "
                   "and driver status; exit 1 if something is missing or busy")
    p.add_argument("--state-dir", type=Path, default=Path("/run/motorctl"),
                   help="where state and the status socket live (default /run/motorctl)")
    p.add_argument("--status", action="store_true",
                   help="print the running daemon's status (JSON) from --state-dir and exit")
    p.add_argument("--log-level", default="info",
                   choices=["debug", "info", "warning", "error"])
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), stream=sys.stderr,
                        format="motorctld %(levelname)s %(name)s: %(message)s")
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
        print(f"{args.check_config}: OK ({len(cfg.motors)} motors, {len(cfg.pins)} pins, "
              f"{'a' if cfg.dc else 'no'} DC motor, backend {cfg.hal.backend})")
        return 0
    if args.probe:
        return probe(args.config)
    if args.status:
        try:
            import json

            print(json.dumps(read_status(args.state_dir / "status.sock"), indent=1))
        except OSError as exc:
            print(f"error: no daemon status at {args.state_dir / 'status.sock'}: {exc}",
                  file=sys.stderr)
            return 1
        return 0
    if args.pty is None and args.port is None:
        print("error: say where to serve: --pty PATH (a pseudo-terminal) or --port DEVICE",
              file=sys.stderr)
        return 2
    try:
        return serve(args)
    except (ConfigError, StartupError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def probe(config_path: str | None) -> int:
    """``--probe``: what the configured hardware looks like, moving nothing."""
    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    report = probe_hardware(config.hal.backend, hardware_spec(config), MonotonicClock())
    print(f"motorctld --probe: config {config.source}, backend {config.hal.backend}")
    sys.stdout.write(report.text())
    return 1 if report.problems else 0


def serve(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    st = config.step_thread
    sys.setswitchinterval(st.switch_interval_us / 1e6)
    if st.priority > 1:
        # Every thread of the daemon inherits SCHED_FIFO one below the step thread, so no
        # ordinary process can preempt a thread while it holds the GIL the step thread needs.
        why = set_realtime(st.priority - 1)
        if why is not None:
            log.warning("SCHED_FIFO not permitted for the daemon's threads (%s)", why)
    if st.cpu >= 0:
        others = os.sched_getaffinity(0) - {st.cpu}
        if others:  # every thread but the step thread keeps off its CPU
            os.sched_setaffinity(0, others)
    daemon = Daemon.build(config, args.state_dir)
    uart: Any = None
    if args.pty is not None:
        fd, name = open_pty(args.pty)
        where = f"{args.pty} -> {name}"
    else:
        uart, fd = open_uart(args.port, args.baud)
        where = f"{args.port} at {args.baud} baud"
    c = config.link
    link = Link(fd, daemon.dispatcher, c.codec_options(), c.frame_gap_ms / 1000.0,
                c.held_frames, on_hangup=None if uart else partial(flush_pty_input, name))
    daemon.link = link
    stepper = StepThread(daemon.engine, daemon.clock, spin_s=st.spin_us / 1e6,
                         priority=st.priority, lock_memory=st.lock_memory, cpu=st.cpu)
    status = StatusServer(args.state_dir / "status.sock", daemon.status)

    def on_signal(signum: int, frame: FrameType | None) -> None:
        link.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    daemon.writer.start()
    stepper.start()
    status.start()
    daemon.writer.request()
    daemon.gc_policy.ready()
    interval = watchdog_interval()
    watchdog = None
    if interval:
        watchdog = Watchdog(interval, lambda: stepper_alive(stepper))
        watchdog.start()
    print(f"motorctld ready: serving {where}; config {config.source}; "
          f"{len(config.motors)} motors; {config.hal.backend} hardware; "
          f"state in {args.state_dir}", flush=True)
    sd_notify("READY=1")
    try:
        link.serve()
    finally:
        sd_notify("STOPPING=1")
        shutdown(daemon, stepper)
        if watchdog is not None:
            watchdog.stop()
        status.close()
        link.close()
        if uart is not None:
            uart.close()
        else:
            os.close(fd)
            if args.pty.is_symlink():
                args.pty.unlink()
        daemon.hw.close()
    log.info("stopped")
    return 0


def stepper_alive(stepper: StepThread) -> bool:
    return stepper.alive


def shutdown(daemon: Daemon, stepper: StepThread) -> None:
    """Stop along the ramps (bounded), brake the DC motor, set safe outputs, write state."""
    engine = daemon.engine
    engine.shutdown()
    deadline = time.monotonic() + SHUTDOWN_LIMIT_S
    while time.monotonic() < deadline:
        with engine.lock:
            if not any(m.active for m in engine.motors):
                break
        time.sleep(0.005)
    with engine.lock:
        now = engine.clock.now()
        for m in engine.motors:
            if m.active:
                log.warning("motor %d did not stop within %.0f s: hard stop", m.index,
                            SHUTDOWN_LIMIT_S)
                m.stop(hard=True, now=now)
    stepper.stop()
    for p in daemon.config.pins:
        pin = daemon.hw.pins.get(p.number)
        if pin is not None and pin.is_output:
            pin.write(p.safe)
    daemon.writer.close()
    gc.enable()


if __name__ == "__main__":
    raise SystemExit(main())
