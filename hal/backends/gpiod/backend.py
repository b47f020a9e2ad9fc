"""The ``gpiod`` hardware backend (:class:`GpiodBackend`, hal/contract.py): steppers
(STEP/DIR/ENABLE), end stops, an H-bridge and user pins on Linux GPIO character devices,
through libgpiod's Python binding (v1 or v2, see :mod:`motorctl.hal.backends.gpiod.chip`).
Consumer name ``motorctl`` (``[gpiod] consumer``).

:meth:`GpiodBackend.build` opens the daemon's part (pins, the bridge, and whatever lines
are named for a motor whose TMC5160 runs its own ramp: held, never stepped) and
:meth:`GpiodBackend.build_step_io` the step executor's (STEP/DIR/ENABLE of the stepped
motors, ``spec.stepped()``, in one request per chip, so several STEP lines rise in one
``set_values`` call; end stops as edge-event requests), whose requests it offers a compiled
core as raw kernel requests (:meth:`GpiodBackend.compiled_lines`). Each first finds every
configured line and checks it is free: a line used twice, a missing chip or line, a line
held by another consumer (named) or a permission problem is an error before anything is
requested. A line the config does not name is never looked up, requested or driven. The
parts are in ``parts.py`` and ``bridge.py``, ``--probe`` in ``probe.py``, the chip API in
``chip.py`` and the wiring in ``wiring.py``.

Threads: the step executor's thread owns the StepIO (outputs, edge inputs); the link thread
owns the pins; a ramp motor's held lines are set only at open and close (main thread); the
engine (under its lock) owns the bridge (bridge.py). Calls block only on GPIO ioctls or
sysfs writes (PWM).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from motorctl.hal.backends.gpiod.bridge import GpiodBridge, PwmChannel
from motorctl.hal.backends.gpiod.chip import GpioApi, LineRequest, LineSettings, load_api
from motorctl.hal.backends.gpiod.config import wiring_of
from motorctl.hal.backends.gpiod.parts import (
    GpiodEdgeInputs,
    GpiodPin,
    GpiodStepOutputs,
    NoDriver,
)
from motorctl.hal.backends.gpiod.probe import probe_gpio
from motorctl.hal.backends.gpiod.wiring import GpioWiring, LineRef, ResolvedLine
from motorctl.hal.compiled_lines import ChardevLines, ChardevRequest, CompiledLines
from motorctl.hal.contract import Backend, ProbeReport
from motorctl.hal.interfaces import (
    Clock,
    EdgeInputs,
    HalError,
    Hardware,
    StepIO,
    StepperHardware,
)
from motorctl.hal.poller import DriverPoller
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import SpiBuses

log = logging.getLogger("motorctl.gpiod")


@dataclass
class GpiodHardware(Hardware):
    """The daemon's part on GPIO lines (pins, the bridge); ``api`` is the binding in use."""

    api: GpioApi | None = None
    lines: list[ResolvedLine] = field(default_factory=list)
    consumer: str = GpioWiring.consumer

    def open_alert_lines(self, uses: Sequence[tuple[str, str]]) -> EdgeInputs:
        """The lines as edge-event requests (pulled up, active low: one request per chip
        on v2, per line on v1), after checking that no other use of the config (a STEP,
        an end stop, a pin, another of these) names one of them and that each is free."""
        api = self.api
        if api is None:
            return super().open_alert_lines(uses)
        refs: list[tuple[str, LineRef]] = []
        for use, text in uses:
            try:
                refs.append((use, LineRef.parse(text)))
            except ValueError as exc:
                raise HalError(f"{use}: {exc}") from exc
        found = api.resolve(refs)
        taken = {(ln.chip_path, ln.offset): ln for ln in self.lines}
        for line in found:
            other = taken.setdefault((line.chip_path, line.offset), line)
            if other is not line:
                raise HalError(
                    f"{line.use}: {line.ref} is {other.chip_path}:{other.offset}, also "
                    f"{other.use} ({other.ref}): a line used twice"
                )
        api.check_free(found)
        settings = LineSettings(bias="pull-up", edges=True)
        try:
            reqs, index = _edge_requests(
                api,
                self.consumer,
                [(i, line, settings) for i, line in enumerate(found)],
                self.closers,
            )
            inputs = GpiodEdgeInputs([u for u, _ in uses], reqs, index, [True] * len(found))
        except OSError as exc:
            raise HalError(f"{', '.join(u for u, _ in uses)}: {exc}") from exc
        self.lines += found
        return inputs


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
    edge_lines: list[tuple[int, ResolvedLine, LineSettings]] = []
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
            edge_lines.append((line_no, found[f"motors[{i}].{which}"], settings))
            pair.append(line_no)
        ends.append((pair[0], pair[1]))
    in_reqs, index = _edge_requests(api, consumer, edge_lines, closers)
    inputs = GpiodEdgeInputs(names, in_reqs, index, lows)
    return StepIO(clock, outputs, inputs, tuple(ends), closers=closers)


def _edge_requests(
    api: GpioApi,
    consumer: str,
    lines: Sequence[tuple[int, ResolvedLine, LineSettings]],
    closers: list[Callable[[], None]],
) -> tuple[list[LineRequest], dict[tuple[int, int], int]]:
    """Edge-event requests for ``lines`` (each its number among the inputs, the line, its
    settings): one request per chip on v2, one per line on v1; each request's release added
    to ``closers`` as it is made. Returns the requests and, for GpiodEdgeInputs, each
    (request, offset)'s input number. The end stops and the alert lines are requested here."""
    groups: dict[str, list[tuple[int, ResolvedLine, LineSettings]]] = {}
    for entry in lines:
        line = entry[1]
        key = line.chip_path if api.name == "v2" else f"{line.chip_path}:{line.offset}"
        groups.setdefault(key, []).append(entry)
    reqs: list[LineRequest] = []
    index: dict[tuple[int, int], int] = {}
    for group in groups.values():
        req = api.request(consumer, [(line, settings) for _, line, settings in group])
        closers.append(req.release)
        for number, line, _ in group:
            index[(len(reqs), line.offset)] = number
        reqs.append(req)
    return reqs, index


def _chardev_lines(outputs: GpiodStepOutputs, inputs: GpiodEdgeInputs) -> ChardevLines | str:
    """The step IO's requests as kernel line requests, for a compiled core's ioctls (the
    capability "lines a compiled core may drive"), or why they cannot be had."""
    outs: list[ChardevRequest] = []
    for req in outputs.reqs:
        raw = req.raw()
        if isinstance(raw, str):
            return f"{req.chip_path}: {raw}"
        outs.append(raw)
    ins: list[ChardevRequest] = []
    for req in inputs.reqs:
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
        tuple(tuple(inputs.index[(r, off)] for off in raw.offsets) for r, raw in enumerate(ins)),
        tuple(inputs.active_low),
    )


class GpiodBackend(Backend):
    """Steppers, end stops, an H-bridge and user pins on GPIO lines through libgpiod."""

    name = "gpiod"

    def build(self, spec: HardwareSpec, clock: Clock, *, for_probe: bool = False) -> Hardware:
        """The daemon's hardware: pins, the DC bridge and the lines named for motors whose
        TMC5160 runs its own ramp (STEP/DIR held low, ENABLE on, off at close; off also
        ``for_probe``). The stepped motors' STEP/DIR/ENABLE and end stops are the step
        executor's (:meth:`build_step_io`). Every configured line is found and checked
        first."""
        wiring = wiring_of(spec)
        api = load_api(wiring.api)
        # every line, the step executor's too: it may open them in another process, where an
        # error could only say that the process failed
        found = resolve(api, wiring)
        consumer = wiring.consumer
        hw = GpiodHardware(
            clock,
            [StepperHardware(NoDriver()) for _ in spec.axes],  # no status: nothing to poll
            {},
            None,
            DriverPoller(clock),
            SpiBuses(),
            api=api,
            lines=list(found.values()),
            consumer=consumer,
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

    def build_step_io(
        self, spec: HardwareSpec, clock: Clock, parent: Hardware | None, *, enable: bool = True
    ) -> StepIO:
        """The step executor's lines: the STEP/DIR/ENABLE of every motor in
        ``spec.stepped()`` (one request per chip, all motors on it together) and their end
        stops as edge-event requests. ENABLE goes on here and off at close (unless
        ``enable`` is False: ``--probe``). Opened in the executor's thread or process (a
        request cannot be inherited). A motor whose TMC5160 runs its own ramp is not
        here."""
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

    def compiled_lines(self, io: StepIO) -> CompiledLines | str:
        """The step IO's requests as kernel line requests, for a compiled core's ioctls,
        or why they cannot be had."""
        if not isinstance(io.outputs, GpiodStepOutputs) or not isinstance(
            io.inputs, GpiodEdgeInputs
        ):
            return "not the gpiod backend's step IO"
        return _chardev_lines(io.outputs, io.inputs)

    def probe(self, spec: HardwareSpec, clock: Clock, report: ProbeReport) -> None:
        """What ``motorctld --probe`` shows for the GPIO side (``probe.py``); opens lines,
        moves nothing."""
        probe_gpio(self, spec, clock, report)
