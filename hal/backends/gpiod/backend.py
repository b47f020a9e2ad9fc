"""The ``gpiod`` hardware backend: steppers (STEP/DIR/ENABLE), end stops, an H-bridge and user
pins on Linux GPIO character devices, through libgpiod's Python binding (v1 or v2, see
:mod:`motorctl.hal.backends.gpiod.chip`). Consumer name ``motorctl`` (``[gpiod] consumer``).

Over 500 lines on purpose: the backend's two entry points and every part they build
(pins, step outputs, edge inputs, the PWM bridge, the probe) share the line resolution and
its checks; the chip API (``chip.py``) and the wiring (``wiring.py``) are already apart.

Two entry points (hal/registry.py): :func:`build` opens the daemon's part (pins, the bridge,
and whatever lines are named for a motor whose TMC5160 runs its own ramp: held, never
stepped) and :func:`build_step_io` the step executor's (STEP/DIR/ENABLE of the stepped
motors, ``spec.stepped()``, in one request per chip, so several STEP lines rise in one
``set_values`` call; end stops as edge-event requests). Each first finds every configured
line and checks it is free: a line used twice, a missing chip or line, a line held by
another consumer (named) or a permission problem is an error before anything is requested.
A line the config does not name is never looked up, requested or driven.

Threads: the step executor's thread owns the StepIO (outputs, edge inputs); the link thread
owns the pins; a ramp motor's held lines are set only at open and close (main thread); the
engine (under its lock) owns the bridge, whose reversal dead time is finished by the
bridge's own small timer thread. Calls block only on GPIO ioctls, sysfs writes (PWM) or a
step pulse's busy-wait. Run-time failures on the step path raise HalIOError.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from motorctl.hal.backends.gpiod.boards import describe_chip, layout
from motorctl.hal.backends.gpiod.chip import (
    GpioApi,
    LineRequest,
    LineSettings,
    chip_list,
    load_api,
)
from motorctl.hal.backends.gpiod.config import (
    AxisRole,
    GpiodAxisConfig,
    GpiodConfig,
    GpiodPinConfig,
    WiringMissing,
    wiring_from,
)
from motorctl.hal.backends.gpiod.wiring import (
    DcWiring,
    GpioWiring,
    MotorWiring,
    PwmWiring,
    ResolvedLine,
)
from motorctl.hal.interfaces import (
    BridgeState,
    ChardevLines,
    ChardevRequest,
    Clock,
    DcBridge,
    DriverStatus,
    Edge,
    EdgeInputs,
    HalError,
    HalIOError,
    Hardware,
    Pin,
    ProbeReport,
    StepIO,
    StepOutputs,
    StepperDriver,
    StepperHardware,
)
from motorctl.hal.spec import AxisSpec, HardwareSpec

log = logging.getLogger("motorctl.gpiod")


def wiring_of(spec: HardwareSpec) -> GpioWiring:
    """The wiring from the config sections ([gpiod], [motors.gpiod], [pins.gpiod])."""
    try:
        return wiring_from(
            spec.sections.get(GpiodConfig),
            [a.sections.get(GpiodAxisConfig) for a in spec.axes],
            [(p.number, p.sections.get(GpiodPinConfig)) for p in spec.pins],
            spec.dc,
            [AxisRole(a.name, a.own_ramp) for a in spec.axes],
        )
    except WiringMissing as exc:
        raise HalError(str(exc)) from None


# --------------------------------------------------------------------------------------------
# parts


class GpiodPin(Pin):
    """A user pin on its own single-line request."""

    def __init__(
        self, number: int, req: LineRequest, offset: int, output: bool, level: bool, bias: str
    ) -> None:
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


class GpiodStepOutputs(StepOutputs):
    """STEP/DIR of every stepped motor (``spec.stepped()``): one request per chip holding all
    their STEP, DIR (and ENABLE) lines on it, so several STEP lines go out in one
    ``set_values`` call."""

    def __init__(
        self,
        clock: Clock,
        motors: Sequence[tuple[MotorWiring, AxisSpec]],
        reqs: list[LineRequest],
        steps: list[tuple[int, int]],
        dirs: list[tuple[int, int]],
    ) -> None:
        super().__init__(
            clock,
            [a.invert_dir for _, a in motors],
            [a.dir_setup_s for _, a in motors],
            [max(m.dir_hold_us / 1e6, a.dir_hold_s) for m, a in motors],
        )
        self.reqs = reqs
        self.steps = steps  # motor -> (request index, STEP offset)
        self.dirs = dirs  # motor -> (request index, DIR offset)

    def _write_dir(self, motor: int, level: bool) -> None:
        r, off = self.dirs[motor]
        try:
            self.reqs[r].set_values({off: level})
        except OSError as exc:
            raise HalIOError(f"motor {motor}: DIR write failed: {exc}") from exc

    def _write_steps(self, motors: Sequence[int], level: bool) -> None:
        steps = self.steps
        try:
            if len(self.reqs) == 1:
                self.reqs[0].set_values({steps[m][1]: level for m in motors})
                return
            by_req: dict[int, dict[int, bool]] = {}
            for m in motors:
                r, off = steps[m]
                by_req.setdefault(r, {})[off] = level
            for r, values in by_req.items():
                self.reqs[r].set_values(values)
        except OSError as exc:
            raise HalIOError(f"motors {list(motors)}: STEP write failed: {exc}") from exc


class GpiodEdgeInputs(EdgeInputs):
    """End stops as kernel edge events (CLOCK_MONOTONIC timestamps); never polled per step.

    On v2 the end stops of one chip share one request (and the kernel debounces); v1 has one
    request per line. ``fileno`` is the request's descriptor when there is one request.
    """

    def __init__(
        self,
        names: list[str],
        reqs: list[LineRequest],
        index: dict[tuple[int, int], int],
        active_low: list[bool],
    ) -> None:
        super().__init__(names)
        self.reqs = reqs
        self.index = index  # (request, offset) -> line
        self.active_low = active_low
        self.levels = [False] * len(names)
        for (r, off), line in index.items():
            self.levels[line] = reqs[r].get_values([off])[0] != active_low[line]

    def read_edges(self) -> list[Edge]:
        out: list[Edge] = []
        try:
            for r, req in enumerate(self.reqs):
                for e in req.wait_events(0.0):
                    line = self.index[(r, e.offset)]
                    active = e.rising != self.active_low[line]
                    self.levels[line] = active
                    out.append(Edge(line, active, e.timestamp_ns / 1e9))
        except OSError as exc:
            raise HalIOError(f"end stops: reading edge events failed: {exc}") from exc
        out.sort(key=lambda e: e.t)
        return out

    def level(self, line: int) -> bool:
        return self.levels[line]

    def fileno(self) -> int | None:
        return self.reqs[0].fileno() if len(self.reqs) == 1 else None


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
            raise HalError(
                f"dc.pwm: cannot set up {self.dir}: {exc.strerror or exc}; enable the "
                "PWM overlay (dtoverlay=pwm on a Raspberry Pi) and give the daemon's "
                "user write access (group gpio)"
            ) from exc

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

    def __init__(
        self,
        req: LineRequest,
        w: DcWiring,
        offsets: tuple[int, int, int | None],
        pwm: PwmChannel | None,
        clock: Clock,
    ) -> None:
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
                    self._thread = threading.Thread(
                        target=self._run, name="dc-dead-time", daemon=True
                    )
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
    """The daemon's part on GPIO lines (pins, the bridge); ``api`` is the binding in use."""

    api: GpioApi | None = None
    lines: list[ResolvedLine] = field(default_factory=list)


def _step_executor_lines(spec: HardwareSpec) -> Callable[[str], bool]:
    """Selects the lines of the motors a step executor drives (not those of a TMC5160 that
    runs its own ramp: the daemon's part holds any lines named for those)."""
    prefixes = tuple(f"motors[{i}]." for i in spec.stepped())
    return lambda use: use.startswith(prefixes)


def resolve(
    api: GpioApi, wiring: GpioWiring, which: Callable[[str], bool] = lambda u: True
) -> dict[str, ResolvedLine]:
    """Find every configured line (all of them, so any mistake shows before anything opens)
    and check that those ``which`` selects are free."""
    dup = wiring.duplicates()
    if dup:
        raise HalError(dup[0])
    lines = api.resolve(wiring.lines())
    seen: dict[tuple[str, int], str] = {}
    for line in lines:
        key = (line.chip_path, line.offset)
        if key in seen:
            api.check_free([dataclasses.replace(line, use=seen[key]), line])
        seen[key] = line.use
    api.check_free([ln for ln in lines if which(ln.use)])
    return {line.use: line for line in lines}


def _setter(req: LineRequest, offset: int, level: bool) -> Callable[[], None]:
    return lambda: req.set_values({offset: level})


def build(spec: HardwareSpec, clock: Clock, *, for_probe: bool = False) -> Hardware:
    """The daemon's hardware: pins, the DC bridge and the lines named for motors whose TMC5160
    runs its own ramp (STEP/DIR held low, ENABLE on, off at close; off also ``for_probe``).
    The stepped motors' STEP/DIR/ENABLE and end stops are the step executor's
    (:func:`build_step_io`). Every configured line is found and checked first."""
    wiring = wiring_of(spec)
    api = load_api(wiring.api)
    # every line, the step executor's too: it may open them in another process, where an
    # error could only say that the process failed
    found = resolve(api, wiring)
    consumer = wiring.consumer
    hw = GpiodHardware(
        clock,
        [StepperHardware(NoDriver()) for _ in spec.axes],
        {},
        None,
        api=api,
        lines=list(found.values()),
    )
    try:
        _open_daemon_part(hw, api, spec, wiring, found, consumer, clock)
        _hold_ramp_motor_lines(hw, api, wiring, found, consumer, enable=not for_probe)
    except BaseException:
        hw.close()
        raise
    log.info(
        "gpiod %s (%s): %d lines found; pins and bridge requested as %r",
        api.name,
        api.version,
        len(found),
        consumer,
    )
    return hw


def _open_daemon_part(
    hw: GpiodHardware,
    api: GpioApi,
    spec: HardwareSpec,
    wiring: GpioWiring,
    found: dict[str, ResolvedLine],
    consumer: str,
    clock: Clock,
) -> None:
    if wiring.dc is not None:
        w = wiring.dc
        dc = [found["dc.in1"], found["dc.in2"]] + ([found["dc.en"]] if w.en else [])
        if len({ln.chip_path for ln in dc}) != 1:
            raise HalError("dc: IN1, IN2 and EN must be on one chip, so they switch together")
        req = api.request(consumer, [(ln, LineSettings(output=True)) for ln in dc])
        hw.closers.append(req.release)
        pwm = PwmChannel(w.pwm) if w.pwm is not None else None
        bridge = GpiodBridge(
            req, w, (dc[0].offset, dc[1].offset, dc[2].offset if w.en else None), pwm, clock
        )
        hw.closers.append(bridge.close)
        hw.dc = bridge
    wired = {p.number: p for p in wiring.pins}
    for p in spec.pins:
        line = found[f"pins.{p.number}"]
        bias = wired[p.number].bias
        req = api.request(
            consumer, [(line, LineSettings(output=p.output, value=p.initial, bias=bias))]
        )
        hw.closers.append(req.release)
        hw.pins[p.number] = GpiodPin(p.number, req, line.offset, p.output, p.initial, bias)


def _hold_ramp_motor_lines(
    hw: GpiodHardware,
    api: GpioApi,
    wiring: GpioWiring,
    found: dict[str, ResolvedLine],
    consumer: str,
    enable: bool,
) -> None:
    """The lines named for motors whose TMC5160 runs its own ramp: never stepped, so STEP/DIR
    (if named at all) are held low and ENABLE on while the daemon runs, off at close."""
    per_chip: dict[str, list[tuple[ResolvedLine, LineSettings]]] = {}
    enables: list[tuple[ResolvedLine, bool]] = []
    for i, m in enumerate(wiring.motors):
        if not m.own_ramp:
            continue
        for which, ref in (("step", m.step), ("dir", m.dir)):
            if ref is not None:
                line = found[f"motors[{i}].{which}"]
                per_chip.setdefault(line.chip_path, []).append(
                    (line, LineSettings(output=True, value=False))
                )
        if m.enable is not None:
            line = found[f"motors[{i}].enable"]
            per_chip.setdefault(line.chip_path, []).append(
                (line, LineSettings(output=True, value=enable != m.enable_active_low))
            )
            enables.append((line, m.enable_active_low))
    reqs = {}
    for path, lines in per_chip.items():
        req = api.request(consumer, lines)
        hw.closers.append(req.release)
        reqs[path] = req
    for line, off_level in enables:
        hw.closers.append(_setter(reqs[line.chip_path], line.offset, off_level))


def build_step_io(
    spec: HardwareSpec, clock: Clock, parent: Hardware | None, *, enable: bool = True
) -> StepIO:
    """The step executor's lines: the STEP/DIR/ENABLE of every motor in ``spec.stepped()``
    (one request per chip, all motors on it together) and their end stops as edge-event
    requests. ENABLE goes on here and off at close. Opened in the executor's thread or process
    (a request cannot be inherited). A motor whose TMC5160 runs its own ramp is not here."""
    wiring = wiring_of(spec)
    api = load_api(wiring.api)
    found = resolve(api, wiring, _step_executor_lines(spec))
    consumer = wiring.consumer
    closers: list[Callable[[], None]] = []
    try:
        return _open_step_io(api, spec, wiring, found, consumer, clock, enable, closers)
    except BaseException:
        for close in reversed(closers):
            close()
        raise


def _open_step_io(
    api: GpioApi,
    spec: HardwareSpec,
    wiring: GpioWiring,
    found: dict[str, ResolvedLine],
    consumer: str,
    clock: Clock,
    enable: bool,
    closers: list[Callable[[], None]],
) -> StepIO:
    stepped = spec.stepped()
    per_chip: dict[str, list[tuple[ResolvedLine, LineSettings]]] = {}
    for i in stepped:
        m = wiring.motors[i]
        step, dir_ = found[f"motors[{i}].step"], found[f"motors[{i}].dir"]
        if step.chip_path != dir_.chip_path:
            raise HalError(
                f"motors[{i}]: STEP ({step.ref}) and DIR ({dir_.ref}) must be on one "
                "chip, so they are requested together"
            )
        uses = [(step, False), (dir_, False)]
        if m.enable is not None:
            uses.append((found[f"motors[{i}].enable"], enable != m.enable_active_low))
        for line, level in uses:
            per_chip.setdefault(line.chip_path, []).append(
                (line, LineSettings(output=True, value=level))
            )
    paths = list(per_chip)
    reqs: list[LineRequest] = []
    for path in paths:
        req = api.request(consumer, per_chip[path])
        closers.append(req.release)
        reqs.append(req)
    for i in stepped:
        m = wiring.motors[i]
        if m.enable is not None:
            en = found[f"motors[{i}].enable"]
            closers.append(_setter(reqs[paths.index(en.chip_path)], en.offset, m.enable_active_low))

    def at(use: str) -> tuple[int, int]:
        line = found[use]
        return paths.index(line.chip_path), line.offset

    outputs = GpiodStepOutputs(
        clock,
        [(wiring.motors[i], spec.axes[i]) for i in stepped],
        reqs,
        [at(f"motors[{i}].step") for i in stepped],
        [at(f"motors[{i}].dir") for i in stepped],
    )
    # end stops
    names: list[str] = []
    lows: list[bool] = []
    ends: list[tuple[int | None, int | None]] = []
    inputs_by_chip: dict[str, list[tuple[int, ResolvedLine, LineSettings]]] = {}
    for i in stepped:
        m, axis = wiring.motors[i], spec.axes[i]
        pair: list[int | None] = []
        for which, es in (("endstop_min", m.endstop_min), ("endstop_max", m.endstop_max)):
            if es is None:
                pair.append(None)
                continue
            line_no = len(names)
            names.append(f"motors[{i}].{which}")
            lows.append(axis.endstop_active_low)
            debounce = axis.endstop_debounce_s
            settings = LineSettings(bias=es.bias, edges=True, debounce_us=round(debounce * 1e6))
            line = found[f"motors[{i}].{which}"]
            key = line.chip_path if api.name == "v2" else f"{line.chip_path}:{line.offset}"
            inputs_by_chip.setdefault(key, []).append((line_no, line, settings))
            pair.append(line_no)
        ends.append((pair[0], pair[1]))
    in_reqs: list[LineRequest] = []
    index: dict[tuple[int, int], int] = {}
    for group in inputs_by_chip.values():
        req = api.request(consumer, [(line, settings) for _, line, settings in group])
        closers.append(req.release)
        for line_no, line, _ in group:
            index[(len(in_reqs), line.offset)] = line_no
        in_reqs.append(req)
    inputs = GpiodEdgeInputs(names, in_reqs, index, lows)
    io = StepIO(clock, outputs, inputs, tuple(ends), closers=closers)
    lines = _chardev_lines(outputs, in_reqs, index, lows)
    if isinstance(lines, str):
        io.compiled_missing = lines
    else:
        io.compiled = lines
    return io


def _chardev_lines(
    outputs: GpiodStepOutputs,
    in_reqs: list[LineRequest],
    index: dict[tuple[int, int], int],
    lows: list[bool],
) -> ChardevLines | str:
    """The step IO's requests as kernel line requests, for a compiled core's ioctls (the
    capability "lines a compiled core may drive"), or why they cannot be had."""
    outs: list[ChardevRequest] = []
    for req in outputs.reqs:
        raw = req.raw()
        if isinstance(raw, str):
            return f"{req.chip_path}: {raw}"
        outs.append(raw)
    ins: list[ChardevRequest] = []
    for req in in_reqs:
        raw = req.raw()
        if isinstance(raw, str):
            return f"{req.chip_path} (end stops): {raw}"
        ins.append(raw)

    def at(where: tuple[int, int]) -> tuple[int, int]:
        r, off = where
        return r, outs[r].offsets.index(off)

    return ChardevLines(
        tuple(outs),
        tuple(at(w) for w in outputs.steps),
        tuple(at(w) for w in outputs.dirs),
        tuple(ins),
        tuple(tuple(index[(r, off)] for off in raw.offsets) for r, raw in enumerate(ins)),
        tuple(lows),
    )


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
    links = {path: name for name, path in api.aliases().items()}
    report.add(
        f"libgpiod Python API {api.name} ({api.version})",
        [
            f"{describe_chip(c)} ({c.path}"
            + (f"; /dev/{links[c.path]} links to it" if c.path in links else "")
            + ")"
            for c in chips
        ]
        or [chip_list(chips)],
    )
    report.add("board layout", [layout(chips)])
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
        held = (f"held by {info.consumer!r}" if info.consumer else "held") if info.used else "free"
        name = f" {info.name!r}" if info.name else ""
        mode = "output" if info.output else "input"
        rows.append(
            f"{ln.use:<22} {ln.ref!s:<16} -> {os.path.basename(ln.chip_path)}:"
            f"{ln.offset}{name} [{ln.chip_label}] ({mode}, {held})"
        )
    report.add("configured lines (before opening)", rows or ["none"])
    used = {ln.chip_path for ln in lines}
    report.add(
        "chips the config uses",
        [describe_chip(c) for c in chips if c.path in used] or ["none"],
    )
    try:
        api.check_free(lines)
        hw = build(spec, clock, for_probe=True)
    except HalError as exc:
        report.problems.append(str(exc))
        return
    try:
        io = build_step_io(spec, clock, hw, enable=False)
    except HalError as exc:
        hw.close()
        report.problems.append(str(exc))
        return
    report.compiled_lines = io.compiled_text()
    try:
        ends = []
        for i, pair in zip(spec.stepped(), io.endstops, strict=True):
            for which, line in zip(("min", "max"), pair, strict=True):
                if line is not None:
                    active = io.inputs.level(line)
                    level = active != spec.axes[i].endstop_active_low
                    ends.append(
                        f"motors[{i}] {which}: level {int(level)} "
                        f"({'TRIGGERED' if active else 'clear'})"
                    )
        report.add("end stops", ends or ["none wired"])
        pins = [
            f"pin {n}: {'output' if p.is_output else 'input'} level {int(p.read())}"
            for n, p in sorted(hw.pins.items())
        ]
        report.add("pins", pins or ["none"])
        report.add(
            "opened",
            [
                f"all {len(lines)} lines requested as {wiring.consumer!r} "
                "and released; nothing moved"
            ],
        )
    finally:
        io.close()
        hw.close()
