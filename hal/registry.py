"""Backends by name, as python-can's interface registry: a config string picks one.

A backend module provides two entry points:

- ``build(spec, clock) -> Hardware``: what the daemon's process owns (drivers, pins, DC).
- ``build_step_io(spec, clock, parent) -> StepIO``: the STEP/DIR outputs and end-stop inputs
  of every axis, opened by the step executor in the process and thread that uses them.
  ``parent`` is the daemon's :class:`Hardware` when the executor runs in the same process
  (a backend may share state with it, as the mock shares its timeline), None in the
  executor's own process, which rebuilds everything from the picklable ``spec``.

The hardware library is imported only inside the backend module, when it is chosen. A
backend that fails to import is an error that says why and how to fix it; there is no
silent fallback to another backend.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from types import ModuleType
from typing import cast

from motorctl.hal.interfaces import Clock, HalError, Hardware, StepIO
from motorctl.hal.spec import HardwareSpec

Builder = Callable[[HardwareSpec, Clock], Hardware]
StepIOBuilder = Callable[[HardwareSpec, Clock, Hardware | None], StepIO]

#: name -> (module, how to install what it needs)
BACKENDS: dict[str, tuple[str, str]] = {
    "mock": ("motorctl.hal.mock", "nothing: it is part of motorctl"),
}


def _module(backend: str) -> ModuleType:
    try:
        module_name, fix = BACKENDS[backend]
    except KeyError:
        raise HalError(
            f"unknown hardware backend {backend!r}; available: {', '.join(sorted(BACKENDS))}"
        ) from None
    try:
        return importlib.import_module(module_name)
    except ImportError as exc:
        raise HalError(f"hardware backend {backend!r} failed to load: {exc}; needs {fix}") from exc


def open_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> Hardware:
    """The daemon's part of the machine (drivers, pins, DC bridge)."""
    build = cast(Builder, _module(backend).build)
    return build(spec, clock)


def open_step_io(
    backend: str, spec: HardwareSpec, clock: Clock, parent: Hardware | None = None
) -> StepIO:
    """The step executor's lines, opened by (and in) the executor that drives them."""
    build = cast(StepIOBuilder, _module(backend).build_step_io)
    return build(spec, clock, parent)
