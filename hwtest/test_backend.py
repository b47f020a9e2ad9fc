"""The gpiod backend alone on gpio-sim (inside the VM, hwtest/run), both libgpiod APIs:
line look-up errors before anything is requested, several motors' STEP lines set in one
call, DIR hold after a STEP fall."""

from __future__ import annotations

import dataclasses
import os

import pytest

from hwtest import gsim
from hwtest.gpiod_harness import GpiodHarness
from hwtest.layout import MOTORS, axis_section, where
from motorctl.hal.backends.gpiod.chip import load_api
from motorctl.hal.backends.gpiod.config import GpiodAxisConfig
from motorctl.hal.interfaces import HalError, MonotonicClock
from motorctl.hal.registry import open_hardware, open_step_io
from motorctl.hal.spec import HardwareSpec

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")


def spec_with(motors: int, step: str | None = None, dir_: str | None = None) -> HardwareSpec:
    """A spec whose motor 0 has other STEP/DIR lines."""
    h = GpiodHarness()
    spec = h.spec(motors, [], False)
    a0 = axis_section(0)
    a0 = dataclasses.replace(a0, step=step or a0.step, dir=dir_ or a0.dir)
    axes = (dataclasses.replace(spec.axes[0], sections={GpiodAxisConfig: a0}), *spec.axes[1:])
    return dataclasses.replace(spec, axes=axes)


def all_free() -> bool:
    api = load_api(API)
    return not any(api.line_info(c.path, o).used for c in api.chips() for o in range(c.num_lines))


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (
            {"step": "gpiochip7:1"},
            "motors[0].step: no GPIO chip 'gpiochip7' (chips: gpiochip0 [sim-bank0] 32 lines, "
            "gpiochip1 [sim-bank1] 16 lines); chip numbers change between kernels",
        ),
        ({"dir_": "GPIO99"}, "motors[0].dir: no GPIO line named 'GPIO99' on any chip"),
        (
            {"dir_": "gpiochip0:17"},
            "motors[0].dir and motors[0].step are the same line (gpiochip0:17 'GPIO17')",
        ),
        (
            {"step": "sim-bank1:40"},
            "motors[0].step: gpiochip1 [sim-bank1] has 16 lines (0..15), no line 40",
        ),
    ],
)
def test_bad_lines_are_named_and_nothing_is_requested(lines: dict[str, str], message: str) -> None:
    with pytest.raises(HalError) as err:
        open_hardware("gpiod", spec_with(2, lines.get("step"), lines.get("dir_")), MonotonicClock())
    assert message in str(err.value)
    assert all_free(), "a line stayed requested after the error"


def test_several_step_lines_in_one_call() -> None:
    h = GpiodHarness()
    h.open(motors=3)
    try:
        out = h.step_io().outputs
        for m in range(3):
            out.set_direction(m, True)
        gsim.trace_start()
        for _ in range(20):
            out.pulse([0, 1, 2], 5e-6)
        gsim.trace_stop()
        ev = gsim.trace_read()
        steps = {gsim.chip_base() + where(m[0])[1] for m in MOTORS}
        rises = [e for e in ev if e.gpio in steps and e.op == "set" and e.value == 1]
        assert len(rises) == 60
        # one call: the three rises of a pulse are consecutive, no fall in between
        on_steps = [e for e in ev if e.gpio in steps and e.op == "set"]
        for i in range(0, len(on_steps), 6):
            assert [e.value for e in on_steps[i : i + 6]] == [1, 1, 1, 0, 0, 0]
    finally:
        h.close()


def test_dir_is_held_after_the_last_step_fall() -> None:
    spec = spec_with(1)
    a0 = dataclasses.replace(axis_section(0), dir_hold_us=2000.0)
    spec = dataclasses.replace(
        spec, axes=(dataclasses.replace(spec.axes[0], sections={GpiodAxisConfig: a0}),)
    )
    clock = MonotonicClock()
    hw = open_hardware("gpiod", spec, clock)
    io = open_step_io("gpiod", spec, clock, parent=hw)
    try:
        out = io.outputs
        out.set_direction(0, True)
        gsim.trace_start()
        out.pulse([0], 5e-6)
        out.set_direction(0, False)
        gsim.trace_stop()
        ev = gsim.trace_read()
        base = gsim.chip_base()
        step = gsim.changes(gsim.sets(ev, base + where(MOTORS[0][0])[1]))
        fall = [e for e in step if e.value == 0][-1]
        flip = [
            e for e in gsim.changes(gsim.sets(ev, base + where(MOTORS[0][1])[1])) if e.value == 0
        ]
        assert flip and flip[0].ts - fall.ts >= 0.002 * 0.99
    finally:
        io.close()
        hw.close()
