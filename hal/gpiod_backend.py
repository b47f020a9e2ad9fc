"""The ``gpiod`` hardware backend: steppers (STEP/DIR/ENABLE), end stops, an H-bridge and user
pins on Linux GPIO character devices, through libgpiod's Python binding (v1 or v2, see
:mod:`motorctl.hal.gpiochip`). Consumer name ``motorctl`` (``[gpiod] consumer``).

Opening checks everything before it requests anything: every line is found on a chip, no
line has two uses, none is held by another consumer; then the lines are requested
(a motor's lines in one request per chip, shared with the other motors on that chip so
that :meth:`StepGroup.pulse_many` sets several STEP lines in one call; the bridge's lines in
one request; each end stop and each pin in its own).

Threads: the step thread owns the step ports and end stops (it is the only caller once the
daemon runs); the link thread owns the pins; the engine (under its lock) owns the bridge,
whose reversal dead time is finished by the bridge's own small timer thread. All calls block
only on GPIO ioctls, sysfs writes (PWM) or the step pulse's busy-wait.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

from motorctl.hal.gpiochip import Edge, GpioApi, LineRequest, LineSettings, load_api
from motorctl.hal.gpiod_config import (
    GpiodAxisConfig,
    GpiodConfig,
    GpiodPinConfig,
    WiringMissing,
    wiring_from,
)
from motorctl.hal.interfaces import (
    BridgeState,
    Clock,
    DcBridge,
    DriverStatus,
    HalError,
    Hardware,
    InputLine,
    Pin,
    StepperDriver,
    StepperHardware,
    StepPort,
)
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.wiring import (
    DcWiring,
    EndstopWiring,
    GpioWiring,
    ProbeReport,
    PwmWiring,
    ResolvedLine,
)

log = logging.getLogger("motorctl.gpiod")


def wiring_of(spec: HardwareSpec) -> GpioWiring:
    """The wiring from the config sections ([gpiod], [motors.gpiod], [pins.gpiod])."""
    try:
        return wiring_from(
            spec.sections.get(GpiodConfig),
            [a.sections.get(GpiodAxisConfig) for a in spec.axes],
            [(p.number, p.sections.get(GpiodPinConfig)) for p in spec.pins],
            spec.dc,
        )
    except WiringMissing as exc:
        raise HalError(str(exc)) from None


# --------------------------------------------------------------------------------------------
# parts


class GpiodPin(Pin):
    """A user pin on its own single-line request."""

    def __init__(self, number: int, req: LineRequest, offset: int, output: bool, level: bool,
                 bias: str) -> None:
        super().__init__(number, output, level)
        self.req = req
        self.offset = offset
        self.bias = bias

    def _configure(self, output: bool, level: bool) -> None:
        self.req.reconfigure(self.offset, LineSettings(output=output, value=level, bias=self.bias))

    def _write(self, level: bool) -> None:
        self.req.set_values({self.offset: level})

    def _read(self) -> bool:
        return self.req.get_values([self.offset])[0]


class GpiodEndstop(InputLine):
    """An end stop as kernel edge events; ``read`` is the level after the last event.

    ``edges`` keeps the events (with their kernel CLOCK_MONOTONIC timestamps) that
    ``read``/``poll`` consumed, newest last, for the executor and the tests.
    """

    def __init__(self, req: LineRequest, offset: int) -> None:
        self.req = req
        self.offset = offset
        self.level = req.get_values([offset])[0]
        self.edges: list[Edge] = []

    def poll(self, timeout_s: float = 0.0) -> list[Edge]:
        """Events that arrived (waiting up to ``timeout_s``); updates the level."""
        evs = self.req.wait_events(timeout_s)
        if evs:
            self.level = evs[-1].rising
            self.edges = (self.edges + evs)[-64:]
        return evs

    def read(self) -> bool:
        self.poll(0.0)
        return self.level

    def fileno(self) -> int:
        return self.req.fileno()


class StepGroup:
    """The STEP/DIR/ENABLE lines of every motor on one chip, in one request."""

    def __init__(self, req: LineRequest, clock: Clock) -> None:
        self.req = req
        self.clock = clock

    def pulse_many(self, ports: list[GpiodStepPort], width_s: float) -> float:
        """One step on each port, all rising in one set_values call; returns the rise time."""
        for p in ports:
            if p.direction is None:
                raise RuntimeError("step pulse before a direction was set")
        self.req.set_values({p.step: True for p in ports})
        rise = self.clock.now()
        self.clock.spin_until(rise + width_s)
        self.req.set_values({p.step: False for p in ports})
        fall = self.clock.now()
        for p in ports:
            p.last_fall = fall
        return rise


class GpiodStepPort(StepPort):
    """STEP and DIR of one driver. DIR waits ``dir_hold_s`` after the last STEP fall."""

    def __init__(self, clock: Clock, invert: bool, group: StepGroup, step: int, dir_: int,
                 dir_hold_s: float) -> None:
        super().__init__(clock, invert)
        self.group = group
        self.step = step
        self.dir = dir_
        self.dir_hold_s = dir_hold_s
        self.last_fall = float("-inf")

    def _write_dir(self, level: bool) -> None:
        ready = self.last_fall + self.dir_hold_s
        if self.clock.now() < ready:
            self.clock.spin_until(ready)
        self.group.req.set_values({self.dir: level})

    def _pulse(self, width_s: float) -> float:
        req, clock = self.group.req, self.clock
        req.set_values({self.step: True})
        rise = clock.now()
        clock.spin_until(rise + width_s)
        req.set_values({self.step: False})
        self.last_fall = clock.now()
        return rise


class NoDriver(StepperDriver):
    """A driver without a status channel (step/dir only): always healthy."""

    def status(self) -> DriverStatus:
        return DriverStatus()


class PwmChannel:
    """A kernel PWM channel through sysfs (``/sys/class/pwm/pwmchipN/pwmM``)."""

    def __init__(self, w: PwmWiring) -> None:
        self.w = w
        chip = os.path.join(w.sysfs, f"pwmchip{w.chip}")
        self.dir = os.path.join(chip, f"pwm{w.channel}")
        try:
            if not os.path.isdir(self.dir):
                self._write(os.path.join(chip, "export"), str(w.channel))
            self._write(os.path.join(self.dir, "enable"), "0")
            self._write(os.path.join(self.dir, "duty_cycle"), "0")
            self._write(os.path.join(self.dir, "period"), str(w.period_ns))
            self._write(os.path.join(self.dir, "enable"), "1")
        except OSError as exc:
            raise HalError(f"dc.pwm: cannot set up {self.dir}: {exc.strerror or exc}; enable the "
                           "PWM overlay (dtoverlay=pwm on a Raspberry Pi) and give the daemon's "
                           "user write access (group gpio)") from exc

    @staticmethod
    def _write(path: str, value: str) -> None:
        with open(path, "w") as f:
            f.write(value)

    def set(self, fraction: float) -> None:
        duty = round(self.w.period_ns * min(1.0, max(0.0, fraction)))
        self._write(os.path.join(self.dir, "duty_cycle"), str(duty))

    def close(self) -> None:
        try:
            self.set(0.0)
            self._write(os.path.join(self.dir, "enable"), "0")
        except OSError as exc:
            log.warning("dc.pwm: %s", exc)


#: IN1, IN2, EN per state
BRIDGE_LEVELS = {
    BridgeState.FORWARD: (True, False, True),
    BridgeState.REVERSE: (False, True, True),
    BridgeState.BRAKE: (True, True, True),
    BridgeState.COAST: (False, False, False),
}


class GpiodBridge(DcBridge):
    """An H-bridge on IN1/IN2 (+EN or PWM). A reversal passes through ``reverse_via`` for the
    dead time; the bridge's timer thread applies the new direction when it is over."""

    def __init__(self, req: LineRequest, w: DcWiring, offsets: tuple[int, int, int | None],
                 pwm: PwmChannel | None, clock: Clock) -> None:
        super().__init__()
        self.req = req
        self.w = w
        self.in1, self.in2, self.en = offsets
        self.pwm = pwm
        self.clock = clock
        self.driven = BridgeState.COAST
        self.via = BridgeState.COAST if w.reverse_via == "coast" else BridgeState.BRAKE
        self._cond = threading.Condition()
        self._pending: tuple[float, BridgeState] | None = None
        self._thread: threading.Thread | None = None
        self._closed = False

    def _drive(self, state: BridgeState) -> None:
        a, b, en = BRIDGE_LEVELS[state]
        values = {self.in1: a, self.in2: b}
        if self.en is not None:
            values[self.en] = en
        self.req.set_values(values)
        if self.pwm is not None:
            run = state in (BridgeState.FORWARD, BridgeState.REVERSE)
            self.pwm.set(self.pwm.w.duty if run else (1.0 if en else 0.0))
        self.driven = state

    def _apply(self, state: BridgeState) -> None:
        with self._cond:
            self._pending = None
            runs = (BridgeState.FORWARD, BridgeState.REVERSE)
            reversal = state in runs and self.driven in runs and state is not self.driven
            if reversal and self.w.dead_time_ms > 0:
                self._drive(self.via)
                self._pending = (self.clock.now() + self.w.dead_time_ms / 1000.0, state)
                if self._thread is None:
                    self._thread = threading.Thread(target=self._run, name="dc-dead-time",
                                                    daemon=True)
                    self._thread.start()
                self._cond.notify()
            else:
                self._drive(state)

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                if self._pending is None:
                    self._cond.wait()
                    continue
                due, state = self._pending
                left = due - self.clock.now()
                if left > 0:
                    self._cond.wait(left)
                    continue
                self._pending = None
                self._drive(state)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._pending = None
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(5.0)
        if self.pwm is not None:
            self.pwm.close()


# --------------------------------------------------------------------------------------------
# opening


@dataclass
class GpiodHardware(Hardware):
    """Hardware on GPIO lines; ``api`` is the libgpiod binding in use."""

    api: GpioApi | None = None
    lines: list[ResolvedLine] = field(default_factory=list)
    groups: dict[str, StepGroup] = field(default_factory=dict)
    endstops: list[GpiodEndstop] = field(default_factory=list)


def resolve(api: GpioApi, wiring: GpioWiring) -> dict[str, ResolvedLine]:
    """Find and check every configured line before anything is requested."""
    dup = wiring.duplicates()
    if dup:
        raise HalError("; ".join(dup))
    lines = api.resolve(wiring.lines())
    api.check_free(lines)
    return {line.use: line for line in lines}


def _setter(req: LineRequest, offset: int, level: bool) -> Callable[[], None]:
    return lambda: req.set_values({offset: level})


def _input(api: GpioApi, consumer: str, line: ResolvedLine, es: EndstopWiring,
           debounce_s: float) -> GpiodEndstop:
    settings = LineSettings(bias=es.bias, edges=True, debounce_us=round(debounce_s * 1e6))
    return GpiodEndstop(api.request(consumer, [(line, settings)]), line.offset)


def build(spec: HardwareSpec, clock: Clock, *, for_probe: bool = False) -> Hardware:
    """The backend's entry point for :mod:`motorctl.hal.registry`."""
    wiring = wiring_of(spec)
    api = load_api(wiring.api)
    found = resolve(api, wiring)
    consumer = wiring.consumer
    hw = GpiodHardware(clock, [], {}, None, api=api, lines=list(found.values()))
    try:
        _open(hw, api, spec, wiring, found, consumer, clock, enable=not for_probe)
    except BaseException:
        hw.close()
        raise
    log.info("gpiod %s (%s): %d lines requested as %r", api.name, api.version, len(found),
             consumer)
    return hw


def _open(hw: GpiodHardware, api: GpioApi, spec: HardwareSpec, wiring: GpioWiring,
          found: dict[str, ResolvedLine], consumer: str, clock: Clock, enable: bool) -> None:
    # steppers: one request per chip for all motors' STEP/DIR/ENABLE lines
    per_chip: dict[str, list[tuple[ResolvedLine, LineSettings]]] = {}
    for i, m in enumerate(wiring.motors):
        uses = [(f"motors[{i}].step", False), (f"motors[{i}].dir", False)]
        if m.enable is not None:
            uses.append((f"motors[{i}].enable", enable != m.enable_active_low))
        for use, level in uses:
            line = found[use]
            per_chip.setdefault(line.chip_path, []).append((line, LineSettings(output=True,
                                                                               value=level)))
    for path, lines in per_chip.items():
        req = api.request(consumer, lines)
        hw.closers.append(req.release)
        hw.groups[path] = StepGroup(req, clock)
    for i, (m, axis) in enumerate(zip(wiring.motors, spec.axes, strict=True)):
        step, dir_ = found[f"motors[{i}].step"], found[f"motors[{i}].dir"]
        if step.chip_path != dir_.chip_path:
            raise HalError(f"motors[{i}]: STEP ({step.ref}) and DIR ({dir_.ref}) must be on one "
                           "chip, so they are requested together")
        group = hw.groups[step.chip_path]
        port = GpiodStepPort(clock, axis.invert_dir, group, step.offset, dir_.offset,
                             m.dir_hold_us / 1e6)
        ends: dict[str, GpiodEndstop | None] = {}
        for which, es in (("endstop_min", m.endstop_min), ("endstop_max", m.endstop_max)):
            ends[which] = None
            if es is not None:
                e = _input(api, consumer, found[f"motors[{i}].{which}"], es, axis.debounce_s)
                hw.closers.append(e.req.release)
                hw.endstops.append(e)
                ends[which] = e
        if m.enable is not None:
            en = found[f"motors[{i}].enable"]
            hw.closers.append(_setter(group.req, en.offset, m.enable_active_low))
        hw.steppers.append(StepperHardware(port, NoDriver(), ends["endstop_min"],
                                           ends["endstop_max"]))
    # the H-bridge
    if wiring.dc is not None:
        w = wiring.dc
        dc = [found["dc.in1"], found["dc.in2"]] + ([found["dc.en"]] if w.en else [])
        if len({ln.chip_path for ln in dc}) != 1:
            raise HalError("dc: IN1, IN2 and EN must be on one chip, so they switch together")
        req = api.request(consumer, [(ln, LineSettings(output=True)) for ln in dc])
        hw.closers.append(req.release)
        pwm = PwmChannel(w.pwm) if w.pwm is not None else None
        bridge = GpiodBridge(req, w, (dc[0].offset, dc[1].offset,
                                      dc[2].offset if w.en else None), pwm, clock)
        hw.closers.append(bridge.close)
        hw.dc = bridge
    # user pins
    wired = {p.number: p for p in wiring.pins}
    for p in spec.pins:
        line = found[f"pins.{p.number}"]
        bias = wired[p.number].bias
        req = api.request(consumer, [(line, LineSettings(output=p.output, value=p.initial,
                                                         bias=bias))])
        hw.closers.append(req.release)
        hw.pins[p.number] = GpiodPin(p.number, req, line.offset, p.output, p.initial, bias)


# --------------------------------------------------------------------------------------------
# probe


def probe(spec: HardwareSpec, clock: Clock, report: ProbeReport) -> None:
    """What ``motorctld --probe`` shows for the GPIO side; opens lines, moves nothing.

    Outputs are requested at their resting levels: STEP low, ENABLE off, the bridge
    coasting, pins at their initial levels.
    """
    wiring = wiring_of(spec)
    api = load_api(wiring.api)
    chips = api.chips()
    report.add(f"libgpiod Python API {api.name} ({api.version})",
               [f"{c.name} [{c.label}] {c.num_lines} lines ({c.path})" for c in chips])
    dup = wiring.duplicates()
    if dup:
        report.problems += dup
        return
    try:
        lines = api.resolve(wiring.lines())
    except HalError as exc:
        report.problems.append(str(exc))
        return
    rows = []
    for ln in lines:
        info = api.line_info(ln.chip_path, ln.offset)
        held = (f"held by {info.consumer!r}" if info.consumer else "held") if info.used \
            else "free"
        name = f" {info.name!r}" if info.name else ""
        mode = "output" if info.output else "input"
        rows.append(f"{ln.use:<22} {ln.ref!s:<16} -> {os.path.basename(ln.chip_path)}:"
                    f"{ln.offset}{name} ({mode}, {held})")
    report.add("configured lines (before opening)", rows)
    try:
        api.check_free(lines)
        hw = build(spec, clock, for_probe=True)
    except HalError as exc:
        report.problems.append(str(exc))
        return
    try:
        assert isinstance(hw, GpiodHardware)
        ends = []
        for i, (st, axis) in enumerate(zip(hw.steppers, spec.axes, strict=True)):
            for which, e in (("min", st.endstop_min), ("max", st.endstop_max)):
                if e is not None:
                    level = e.read()
                    active = level != axis.endstop_active_low
                    ends.append(f"motors[{i}] {which}: level {int(level)} "
                                f"({'TRIGGERED' if active else 'clear'})")
        report.add("end stops", ends or ["none wired"])
        pins = [f"pin {n}: {'output' if p.is_output else 'input'} level {int(p.read())}"
                for n, p in sorted(hw.pins.items())]
        report.add("pins", pins or ["none"])
        report.add("opened", [f"all {len(hw.lines)} lines requested as {wiring.consumer!r} "
                              "and released; nothing moved"])
    finally:
        hw.close()
