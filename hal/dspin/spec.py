"""A motor's dSPIN chip as the config gives it (:class:`DspinSpec`): the driver spec the dSPIN
layer opens (``hal/layers/dspin/``) and the mock backend simulates (its chain of chip
models, ``hal/backends/mock/dspin_chain.py``). Both read it and neither may import the
other (tests/test_imports.py), so it is declared here, beside the datasheet tables.

Pure, picklable data: any thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from motorctl.hal.dspin.counter import ABS_POS_MAX, ABS_POS_MIN
from motorctl.hal.spec import DriverSpec, HardwareSpec
from motorctl.hal.spi import DEFAULT_SPEED_HZ

#: the sides the chip's SW input can be wired to (``none``: no switch on SW)
SWITCH_SIDES = ("min", "max", "none")

if TYPE_CHECKING:  # the chips' tables are imported where a model is asked for (light config)
    from motorctl.hal.dspin.chips import Chip


@dataclass(frozen=True)
class DspinSpec(DriverSpec):
    """One motor's chip: ``chip`` (a key of :data:`~motorctl.hal.dspin.chips.CHIPS`) at
    ``position`` (0 = the chip whose SDI is the host's MOSI) in the chain on ``spi``;
    ``registers``: the values written at start (register name -> value) beyond those
    derived from ``step_mode`` (STEP_MODE, from ``microsteps``); ``switch``: the end stop
    wired to the chip's SW input (``min``, ``max``, ``none``); ``flag``, ``busy``: the
    GPIO lines the chip's FLAG and BUSY outputs are wired to (a backend's line text; ""
    not wired; chips of one chain may share one, wired-OR); ``rotary``: the motor's axis
    turns without end (``steps_per_rev`` > 0): its positions go on past ABS_POS's 22 bits,
    which the chip wraps as it turns, and the driver counts them on (no ``counter_range``)."""

    spi: str
    position: int
    chip: str
    steps_per_full: int  # microsteps per full step (STEP_SEL)
    registers: tuple[tuple[str, int], ...] = ()
    switch: str = "min"
    spi_speed_hz: int = DEFAULT_SPEED_HZ
    hiz_at_exit: bool = True
    flag: str = ""
    busy: str = ""
    rotary: bool = False

    @property
    def own_ramp(self) -> bool:
        return True

    @property
    def microsteps(self) -> int | None:
        return self.steps_per_full

    @property
    def counter_range(self) -> tuple[int, int] | None:
        """ABS_POS: 22 bits of microsteps, two's complement; None on a rotary axis (the
        driver counts on past them)."""
        if self.rotary:
            return None
        return ABS_POS_MIN, ABS_POS_MAX

    @property
    def model(self) -> Chip:
        from motorctl.hal.dspin.chips import CHIPS

        return CHIPS[self.chip]


def chains(spec: HardwareSpec) -> dict[str, list[tuple[int, DspinSpec]]]:
    """The dSPIN chains of a machine: device node -> (axis index, its spec) by position in
    the chain (the config checked that positions run 0..N-1 on each node)."""
    found: dict[str, list[tuple[int, DspinSpec]]] = {}
    for i, axis in enumerate(spec.axes):
        if isinstance(axis.driver, DspinSpec):
            found.setdefault(axis.driver.spi, []).append((i, axis.driver))
    for members in found.values():
        members.sort(key=lambda m: m[1].position)
    return found
