"""Backends and layers by name, as python-can's interface table: a config string picks one.

Each name maps to two classes of the contract (hal/contract.py), each written
``"module:Class"`` and imported only when asked for:

- its declaration (:class:`~motorctl.hal.contract.BackendDeclaration`,
  :class:`~motorctl.hal.contract.LayerDeclaration`), in a module that imports no hardware
  library: imported whenever a config is read (its sections, the checks);
- its implementation (:class:`~motorctl.hal.contract.Backend`,
  :class:`~motorctl.hal.contract.Layer`), imported only when the config uses it: it may
  import its hardware library. One that fails to import is an error that says why and how
  to fix it; there is no silent fallback to another backend.

What is loaded is checked against the table: a class that is not the contract's kind is an
error naming it (the type checker checks each class against its ABC, and tests/hal/
test_registry.py instantiates every one). Nothing outside hal/ names a backend's or a layer's
module (tests/test_imports.py): the daemon and motion ask the functions below.

A layer (``LAYERS``) works with any backend: the TMC layer attaches a TMC2130/TMC5160 over
SPI to a motor whose config has a ``[motors.tmc]`` table, when its declaration's
``applies(spec)`` says the config uses it.

Adding a backend: write ``hal/backends/<name>/config.py`` with its declaration (its
``@section`` dataclasses as ``motorctl.schema`` Extensions: parent "" = top-level
``[<name>]``, "motors" = ``[motors.<name>]``, "pins" = ``[pins.<name>]``) and
``backend.py`` with its Backend, which reads them from the spec (``spec.section(Cls)``,
``spec.axes[i].section(Cls)``; the daemon passes every section along,
daemon/assemble.hardware_spec); name both in ``BACKENDS``; regenerate docs/config.md
(``python -m motorctl.daemon.config.docs --write``).

The tables are constants; lookups import modules (the import system's lock) and are
otherwise pure: any thread.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from motorctl.hal.contract import (
    Backend,
    BackendDeclaration,
    Layer,
    LayerDeclaration,
    MotorEntry,
    ProbeReport,
    ProblemKind,
)
from motorctl.hal.interfaces import Clock, HalError, Hardware, StepIO
from motorctl.hal.poller import DriversConfig
from motorctl.hal.spec import DriverSpec, HardwareSpec
from motorctl.schema import Extension


@dataclass(frozen=True)
class Entry:
    """Where a backend or a layer lives: its two classes, each as ``"module:Class"``."""

    declaration: str  # imported whenever a config is read: imports no hardware library
    implementation: str  # imported only when used: may import its hardware library
    fix: str  # how to install what the implementation needs


BACKENDS: dict[str, Entry] = {
    "mock": Entry(
        "motorctl.hal.backends.mock.config:MockDeclaration",
        "motorctl.hal.backends.mock.backend:MockBackend",
        "nothing: it is part of motorctl",
    ),
    "gpiod": Entry(
        "motorctl.hal.backends.gpiod.config:GpiodDeclaration",
        "motorctl.hal.backends.gpiod.backend:GpiodBackend",
        "libgpiod's Python binding: pip install 'motorctl[hardware]' (gpiod>=2) or "
        "apt install python3-libgpiod",
    ),
}

#: "tmc": TMC2130/TMC5160 driver chips over /dev/spidevB.C; "dspin": ST dSPIN chains on it
LAYERS: dict[str, Entry] = {
    "tmc": Entry(
        "motorctl.hal.layers.tmc.config:TmcDeclaration",
        "motorctl.hal.layers.tmc.layer:TmcLayer",
        "a complete motorctl install (py-spidev is imported only when a driver opens)",
    ),
    "dspin": Entry(
        "motorctl.hal.layers.dspin.config:DspinDeclaration",
        "motorctl.hal.layers.dspin.layer:DspinLayer",
        "a complete motorctl install (py-spidev is imported only when a chain opens)",
    ),
}


def _load(name: str, ref: str) -> object:
    """An object of the class ``ref`` ("module:Class") names; ImportError when its module
    does not import, HalError when it is not there."""
    module_name, _, class_name = ref.partition(":")
    cls = getattr(importlib.import_module(module_name), class_name, None)
    if not isinstance(cls, type):
        raise HalError(f"{name}: {ref} is not a class")
    return cls()


def backend_declaration(backend: str) -> BackendDeclaration:
    """The declaration of backend ``backend``; HalError for a name not in the table."""
    found = _load(backend, _entry(backend).declaration)
    if not isinstance(found, BackendDeclaration):
        raise HalError(f"backend {backend!r}: {BACKENDS[backend].declaration} is no declaration")
    return found


def layer_declarations() -> dict[str, LayerDeclaration]:
    """Every layer's declaration, by name."""
    out: dict[str, LayerDeclaration] = {}
    for name, entry in LAYERS.items():
        found = _load(name, entry.declaration)
        if not isinstance(found, LayerDeclaration):
            raise HalError(f"layer {name!r}: {entry.declaration} is no layer declaration")
        out[name] = found
    return out


def _entry(backend: str) -> Entry:
    try:
        return BACKENDS[backend]
    except KeyError:
        raise HalError(
            f"unknown hardware backend {backend!r}; available: {', '.join(sorted(BACKENDS))}"
        ) from None


def backend(name: str) -> Backend:
    """Backend ``name``'s implementation, imported now; HalError saying why and how to fix
    it when it cannot be."""
    entry = _entry(name)
    try:
        found = _load(name, entry.implementation)
    except ImportError as exc:
        raise HalError(
            f"hardware backend {name!r} failed to load: {exc}; needs {entry.fix}"
        ) from exc
    if not isinstance(found, Backend):
        raise HalError(f"backend {name!r}: {entry.implementation} is no Backend")
    return found


def layer(name: str) -> Layer:
    """Layer ``name``'s implementation, imported now; HalError saying why and how to fix it
    when it cannot be."""
    entry = LAYERS[name]
    try:
        found = _load(name, entry.implementation)
    except ImportError as exc:
        raise HalError(f"layer {name!r} failed to load: {exc}; needs {entry.fix}") from exc
    if not isinstance(found, Layer):
        raise HalError(f"layer {name!r}: {entry.implementation} is no Layer")
    return found


#: the HAL's own sections, beside its backends' and layers': [drivers] (hal/poller.py)
HAL_SECTIONS: tuple[Extension, ...] = (
    Extension("", "drivers", DriversConfig, owner="the HAL's driver poller"),
)


def config_sections() -> list[tuple[str, tuple[Extension, ...]]]:
    """(the HAL, a backend or a layer name, its config sections): the HAL's own
    (``HAL_SECTIONS``), every backend's and every layer's."""
    found = [("hal", HAL_SECTIONS)]
    found += [(name, backend_declaration(name).sections(driver_spec)) for name in BACKENDS]
    return found + [(name, d.sections()) for name, d in layer_declarations().items()]


def driver_spec(motor: MotorEntry) -> DriverSpec | None:
    """The driver chip a motor's config (a ``[[motors]]`` entry, with its layers' sections)
    gives it, from the layer that declares it; None: no driver chip to talk to. Imports
    declarations only."""
    for declaration in layer_declarations().values():
        found = declaration.driver_spec(motor)
        if found is not None:
            return found
    return None


def motors_lose_steps(name: str, spec: HardwareSpec) -> bool:
    """Whether a late step may cost the backend's motors steps (as the Hardware it builds
    says, ``Hardware.motors_lose_steps``), known without building it (its declaration's
    ``motors_lose_steps``; the mock: ``[mock] lose_steps``). True for an unknown name."""
    if name not in BACKENDS:
        return True
    return backend_declaration(name).motors_lose_steps(spec)


def _applying(spec: HardwareSpec) -> list[str]:
    return sorted(name for name, d in layer_declarations().items() if d.applies(spec))


def open_hardware(name: str, spec: HardwareSpec, clock: Clock) -> Hardware:
    """The daemon's part of the machine (drivers, pins, DC bridge), with the layers the
    config uses attached (its driver chips), its driver poller at ``[drivers] poll_ms``
    (not started: its consumer starts it)."""
    hw = backend(name).build(spec, clock)
    drivers = spec.sections.get(DriversConfig)
    if drivers is not None:
        hw.poller.period_s = drivers.poll_ms / 1000.0
    try:
        for layer_name in _applying(spec):
            layer(layer_name).attach(hw, spec, clock)
    except BaseException:
        hw.close()
        raise
    return hw


def probe_hardware(name: str, spec: HardwareSpec, clock: Clock) -> ProbeReport:
    """Everything the backend (and each layer the config uses) finds; problems are listed
    in the report, not raised, so one missing device does not hide the rest."""
    report = ProbeReport()
    try:
        backend(name).probe(spec, clock, report)
    except HalError as exc:
        report.problem(str(exc))
    try:
        simulated = backend(name).simulated_spi(spec, clock)
    except HalError:  # already reported above
        simulated = None
    for layer_name in _applying(spec):
        try:
            layer(layer_name).probe(spec, clock, report, simulated)
        except HalError as exc:
            report.problem(f"{layer_name}: {exc}", ProblemKind.DEVICE)
    return report


def open_step_io(
    name: str, spec: HardwareSpec, clock: Clock, parent: Hardware | None = None
) -> StepIO:
    """The step executor's lines, opened by (and in) the executor that drives them."""
    return backend(name).open_step_io(spec, clock, parent)
