"""Backends by name, as python-can's interface registry: a config string picks one.

A backend that fails to import is an error that says why and how to fix it;
there is no silent fallback to another backend.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import cast

from motorctl.hal.interfaces import Clock, HalError, Hardware
from motorctl.hal.spec import HardwareSpec

Builder = Callable[[HardwareSpec, Clock], Hardware]

#: name -> (module, function, how to install what it needs)
BACKENDS: dict[str, tuple[str, str, str]] = {
    "mock": ("motorctl.hal.mock", "build", "nothing: it is part of motorctl"),
}


def open_hardware(backend: str, spec: HardwareSpec, clock: Clock) -> Hardware:
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
    build = cast(Builder, getattr(module, func_name))
    hw = build(spec, clock)
    drivers = [a.driver for a in spec.axes]
    if any(drivers):
        from motorctl.hal.tmc_backend import attach_drivers  # imports py-spidev lazily

        names = [a.name or f"motor {i}" for i, a in enumerate(spec.axes)]
        try:
            attach_drivers(hw, drivers, clock, names)
        except BaseException:
            hw.close()
            raise
    return hw
