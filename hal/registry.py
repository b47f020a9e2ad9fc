"""Backends by name, as python-can's interface registry: a config string picks one.

A backend module provides two entry points:

- ``build(spec, clock) -> Hardware``: what the daemon's process owns (drivers, pins, DC).
- ``build_step_io(spec, clock, parent) -> StepIO``: the STEP/DIR outputs and end-stop inputs
  of the axes ``spec.stepped()`` names (every axis but those whose TMC5160 runs its own ramp;
  the StepIO's motor j is axis ``stepped()[j]``), opened by the step executor in the process
  and thread that uses them.
  ``parent`` is the daemon's :class:`Hardware` when the executor runs in the same process
  (a backend may share state with it, as the mock shares its timeline), None in the
  executor's own process, which rebuilds everything from the picklable ``spec``.

The hardware library is imported only inside the backend module, when it is chosen. A
backend that fails to import is an error that says why and how to fix it; there is no
silent fallback to another backend.

Each backend names two modules: the one that builds it (imported only when the backend is
chosen: it may import its hardware library) and the one that declares its config sections
(imported whenever a config is read: it must import no hardware library). The config module
exports ``CONFIG_SECTIONS``, a tuple of `motorctl.schema.Extension`.

Adding a backend's config section:
  1. write ``hal/backends/<backend>/config.py``: one ``@section`` dataclass per table, whose fields
     declare the keys (`motorctl.schema`), and ``CONFIG_SECTIONS = (Extension("", "<name>",
     TopConfig, owner=...), Extension("motors", "<name>", AxisConfig, owner=...), ...)``
     (parent "" = top-level ``[<name>]``, "motors" = ``[motors.<name>]`` in every motor,
     "pins" = ``[pins.<name>]`` in every pin);
  2. name it in ``BACKENDS`` below;
  3. read it in the backend's build(spec, clock): ``spec.section(TopConfig)``,
     ``spec.axes[i].section(AxisConfig)``, ``spec.pins[i].section(PinConfig)`` (the daemon
     passes every backend's sections along in the HardwareSpec;
     daemon/assemble.hardware_spec);
  4. regenerate docs/config.md: ``python -m motorctl.daemon.config.docs --write``.

A backend module may also define ``probe(spec, clock, report)``: it opens what the config
names without moving anything and adds what it found to a `ProbeReport` (``motorctld
--probe``). A config module may define ``motors_lose_steps(spec)`` (see
:func:`motors_lose_steps`).

Layers (`LAYERS`) work with any backend: the SPI driver layer attaches a TMC2130/TMC5160 to
a motor whose config has a ``[motors.tmc]`` table. A layer names its config module (which
may give a motor its :class:`~motorctl.hal.spec.DriverSpec`, :func:`driver_spec`) and the
module whose ``attach(hw, spec, clock)`` and ``probe(spec, clock, report)`` run when its
``applies(spec)`` says the config uses it.

The registry is a constant; lookups are pure and thread-safe.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any, cast

from motorctl.hal.interfaces import Clock, HalError, Hardware, ProbeReport, StepIO
from motorctl.hal.spec import DriverSpec, HardwareSpec

Builder = Callable[[HardwareSpec, Clock], Hardware]
Attacher = Callable[[Hardware, HardwareSpec, Clock], object]
Prober = Callable[[HardwareSpec, Clock, ProbeReport], None]
StepIOBuilder = Callable[[HardwareSpec, Clock, Hardware | None], StepIO]


@dataclass(frozen=True)
class Backend:
    """Where a backend lives and what it needs."""

    module: str  # builds it: imported only when chosen (may import its hardware library)
    function: str  # the Builder in `module`
    fix: str  # how to install what it needs
    config: str | None = None  # declares its config sections: imports no hardware library


BACKENDS: dict[str, Backend] = {
    "mock": Backend(
        "motorctl.hal.backends.mock.backend",
        "build",
        "nothing: it is part of motorctl",
        "motorctl.hal.backends.mock.config",
    ),
    "gpiod": Backend(
        "motorctl.hal.backends.gpiod.backend",
        "build",
        "libgpiod's Python binding: pip install 'motorctl[hardware]' (gpiod>=2) or "
        "apt install python3-libgpiod",
        "motorctl.hal.backends.gpiod.config",
    ),
}


@dataclass(frozen=True)
class Layer:
    """A part of the machine that works with any backend, attached to what the backend
    built (the SPI layer: driver chips).

    ``module`` has ``attach(hw, spec, clock)`` and ``probe(spec, clock, report)``; it is
    imported only when ``applies(spec)`` (and may import its hardware library). ``config``
    declares the layer's config sections (no hardware library) and may define
    ``driver_spec(motor) -> DriverSpec | None``: a motor's driver chip from its sections.
    """

    module: str
    config: str
    applies: Callable[[HardwareSpec], bool]


def _has_drivers(spec: HardwareSpec) -> bool:
    return any(a.driver is not None for a in spec.axes)


#: "spidev": TMC2130/TMC5160 drivers over /dev/spidevB.C
LAYERS: dict[str, Layer] = {
    "spidev": Layer(
        "motorctl.hal.backends.tmc.backend", "motorctl.hal.backends.tmc.config", _has_drivers
    ),
}


def config_sections() -> list[tuple[str, tuple[Any, ...]]]:
    """(backend or layer name, its CONFIG_SECTIONS) of everything that declares sections."""
    modules = [(name, b.config) for name, b in BACKENDS.items() if b.config is not None]
    found = []
    for name, module_name in [*modules, *((n, layer.config) for n, layer in LAYERS.items())]:
        module = importlib.import_module(module_name)
        found.append((name, tuple(module.CONFIG_SECTIONS)))
    return found


def driver_spec(motor: Any) -> DriverSpec | None:
    """The driver chip a motor's config (a ``[[motors]]`` entry, with its layers' sections)
    gives it, from the layer that declares it; None: no driver chip to talk to. Imports
    config modules only."""
    for layer in LAYERS.values():
        make = getattr(importlib.import_module(layer.config), "driver_spec", None)
        found = None if make is None else cast(DriverSpec | None, make(motor))
        if found is not None:
            return found
    return None


def motors_lose_steps(backend: str, spec: HardwareSpec) -> bool:
    """Whether a late step may cost the backend's motors steps (as the Hardware it builds
    says, ``Hardware.motors_lose_steps``), known without building it: its config module's
    ``motors_lose_steps(spec)`` if it has one (the mock: ``[mock] lose_steps``), else True
    (real rotors)."""
    entry = BACKENDS.get(backend)
    if entry is None or entry.config is None:
        return True
    ask = getattr(importlib.import_module(entry.config), "motors_lose_steps", None)
    return True if ask is None else bool(ask(spec))


def _module(backend: str) -> ModuleType:
    try:
        entry = BACKENDS[backend]
    except KeyError:
        raise HalError(
            f"unknown hardware backend {backend!r}; available: {', '.join(sorted(BACKENDS))}"
        ) from None
    try:
        return importlib.import_module(entry.module)
    except ImportError as exc:
        raise HalError(
            f"hardware backend {backend!r} failed to load: {exc}; needs {entry.fix}"
        ) from exc


def open_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> Hardware:
    """The daemon's part of the machine (drivers, pins, DC bridge), with the layers the
    config uses attached (its driver chips)."""
    build = cast(Builder, getattr(_module(backend), BACKENDS[backend].function))
    hw = build(spec, clock)
    try:
        for layer in LAYERS.values():
            if layer.applies(spec):
                attach = cast(Attacher, importlib.import_module(layer.module).attach)
                attach(hw, spec, clock)
    except BaseException:
        hw.close()
        raise
    return hw


def probe_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> ProbeReport:
    """Everything the backend (and each applicable extra probe) finds; problems are listed
    in the report, not raised, so one missing device does not hide the rest."""
    report = ProbeReport()
    try:
        module = _module(backend)
        own = cast(Prober | None, getattr(module, "probe", None))
        if own is None:
            report.add(f"backend {backend}", ["nothing to probe: no hardware is opened"])
            io = open_step_io(backend, spec, clock)  # no hardware: nothing is opened
            report.compiled_lines = io.compiled_text()
            io.close()
        else:
            own(spec, clock, report)
    except HalError as exc:
        report.problems.append(str(exc))
    for name, layer in sorted(LAYERS.items()):
        if not layer.applies(spec):
            continue
        try:
            extra = cast(Prober, importlib.import_module(layer.module).probe)
            extra(spec, clock, report)
        except (HalError, ImportError) as exc:
            report.problems.append(f"{name}: {exc}")
    return report


def open_step_io(
    backend: str, spec: HardwareSpec, clock: Clock, parent: Hardware | None = None
) -> StepIO:
    """The step executor's lines, opened by (and in) the executor that drives them."""
    build = cast(StepIOBuilder, _module(backend).build_step_io)
    return build(spec, clock, parent)
