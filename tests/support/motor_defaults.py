"""A motor's defaults as the config model declares them ([[motors]] in
daemon/config/model.py, the one place they are written): the records motion and the
platform check take (MotorParams, AxisLimits, MotorRate) have no defaults of their own for
them, so the tests build theirs here, from the declaration.

``declared("start_speed")`` is the declared default of one key; :func:`motor_params`,
:func:`motor_limits` and :func:`motor_rate` the records with those defaults, changed by keyword.
"""

from __future__ import annotations

from typing import Any

from motorctl.daemon.config.model import MICROSTEPS_UNSAID, MotorConfig
from motorctl.daemon.start.platform_check import MotorRate
from motorctl.motion.executors.base import AxisLimits
from motorctl.motion.types import MotorParams
from motorctl.schema import table_of


def declared(name: str) -> Any:
    """The default ``[[motors]]`` declares for key ``name``."""
    keys = {k.name: k for k in table_of(MotorConfig).keys}
    return keys[name].default


#: what MotorParams, AxisLimits and MotorRate are always given: the lag rule's values
LAG_DEFAULTS = {
    "start_speed": declared("start_speed"),
    "max_lag_full_steps": declared("max_lag_full_steps"),
}
#: and MotorParams the rest of a motor's config (microsteps: the assembler's when the config
#: says none)
PARAMS_DEFAULTS = {
    **LAG_DEFAULTS,
    **{k: declared(k) for k in ("steps_per_rev", "queue_depth", "max_waypoints", "max_speed")},
    "microsteps": MICROSTEPS_UNSAID,
}


def motor_params(**changes: Any) -> MotorParams:
    """MotorParams with the declared defaults, ``changes`` applied."""
    return MotorParams(**{**PARAMS_DEFAULTS, **changes})


def motor_limits(min_interval_s: float, **changes: Any) -> AxisLimits:
    """AxisLimits with the declared defaults (microsteps: the assembler's when the config
    says none), ``changes`` applied."""
    return AxisLimits(
        min_interval_s, **{"microsteps": MICROSTEPS_UNSAID, **LAG_DEFAULTS, **changes}
    )


def motor_rate(name: str, max_speed: float, microsteps: int | None, **changes: Any) -> MotorRate:
    """The platform check's MotorRate with the declared defaults, ``changes`` applied."""
    return MotorRate(name, max_speed, microsteps, **{**LAG_DEFAULTS, **changes})
