"""Backends by name, as python-can's interface registry: a config string picks one.

A backend is a module with ``build(spec, clock) -> Hardware`` and, optionally,
``probe(spec, clock, report)`` which opens what the config names without moving anything
and adds what it found to a :class:`~motorctl.hal.wiring.ProbeReport` (``motorctld
--probe``). Besides the backend chosen by ``[hal] backend``, other modules (an SPI driver
layer, for example) can add to the probe through :data:`PROBES`. Modules are imported only
when used, so a hardware library is needed only by the backend that uses it.

A backend that fails to import is an error that says why and how to fix it;
there is no silent fallback to another backend.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from types import ModuleType
from typing import cast

from motorctl.hal.interfaces import Clock, HalError, Hardware
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.wiring import ProbeReport

Builder = Callable[[HardwareSpec, Clock], Hardware]
Prober = Callable[[HardwareSpec, Clock, ProbeReport], None]

#: name -> (module, function, how to install what it needs)
BACKENDS: dict[str, tuple[str, str, str]] = {
    "mock": ("motorctl.hal.mock", "build", "nothing: it is part of motorctl"),
    "gpiod": (
        "motorctl.hal.gpiod_backend",
        "build",
        "libgpiod's Python binding: pip install 'motorctl[hardware]' (gpiod>=2) or "
        "apt install python3-libgpiod",
    ),
}

#: extra probe hooks: name -> (module, function, applies(spec) -> bool). They run after the
#: backend's own probe, each only when ``applies`` says the config uses it.
PROBES: dict[str, tuple[str, str, Callable[[HardwareSpec], bool]]] = {}


def _module(backend: str) -> tuple[ModuleType, str]:
    try:
        module_name, func_name, fix = BACKENDS[backend]
    except KeyError:
        raise HalError(
            f"unknown hardware backend {backend!r}; available: {', '.join(sorted(BACKENDS))}"
        ) from None
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise HalError(f"hardware backend {backend!r} failed to load: {exc}; needs {fix}") from exc
    return module, func_name


def open_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> Hardware:
    module, func_name = _module(backend)
    build = cast(Builder, getattr(module, func_name))
    return build(spec, clock)


def probe_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> ProbeReport:
    """Everything the backend (and any applicable extra probe) finds; problems are listed
    in the report, not raised, so one missing device does not hide the rest."""
    report = ProbeReport()
    try:
        module, _ = _module(backend)
        own = cast(Prober | None, getattr(module, "probe", None))
        if own is None:
            report.add(f"backend {backend}", ["nothing to probe: no hardware is opened"])
        else:
            own(spec, clock, report)
    except HalError as exc:
        report.problems.append(str(exc))
    for name, (module_name, func_name, applies) in sorted(PROBES.items()):
        if not applies(spec):
            continue
        try:
            extra = cast(Prober, getattr(importlib.import_module(module_name), func_name))
            extra(spec, clock, report)
        except (HalError, ImportError) as exc:
            report.problems.append(f"{name}: {exc}")
    return report
