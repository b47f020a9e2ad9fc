"""Which gpio-sim lines the tier wires to what (the VM has hwtest.gsim.BANKS/NAMES).

The motors, end stops, bridge and pins of docs/examples/raspberry-pi.toml use the Raspberry
Pi's line names (GPIO17 ..., ID_SDA/ID_SCL for lines 0 and 1 as on a Pi 4 or 5), which
gpio-sim's bank 0 carries too; the contract tests add ENABLE lines as chip:offset and max end
stops by name on the second chip, to cover every way of naming a line.
"""

from __future__ import annotations

import re
from pathlib import Path

from motorctl.hal.backends.gpiod.config import GpiodAxisConfig, GpiodConfig, GpiodPinConfig, make
from motorctl.hal.backends.gpiod.wiring import LineRef

EXAMPLE = Path(__file__).resolve().parent.parent / "docs" / "examples" / "raspberry-pi.toml"

#: step, dir, enable, min, max
MOTORS = [
    ("GPIO17", "GPIO27", "gpiochip0:28", "GPIO26", "B1_4"),
    ("GPIO22", "GPIO23", "gpiochip0:29", "GPIO16", "B1_5"),
    ("GPIO5", "GPIO6", "gpiochip0:30", "GPIO20", "B1_6"),
]
DC = ("GPIO13", "GPIO19", "GPIO21")  # IN1, IN2, EN
PINS = ["GPIO4", "GPIO25", "GPIO18", "GPIO12", "GPIO2", "GPIO3", "ID_SDA", "ID_SCL"]
#: the Pi's names of header lines 0 and 1 (the HAT ID EEPROM's I2C)
FIRST = {"ID_SDA": 0, "ID_SCL": 1}


def where(text: str) -> tuple[str, int]:
    """The sim chip and offset of a line as this layout writes it."""
    ref = LineRef.parse(text)
    if ref.name is not None:
        if ref.name in FIRST:
            return "gpiochip0", FIRST[ref.name]
        if ref.name.startswith("GPIO"):
            return "gpiochip0", int(ref.name[4:])
        if ref.name.startswith("B1_"):
            return "gpiochip1", int(ref.name[3:])
        raise LookupError(text)
    assert ref.chip is not None and ref.offset is not None
    return ref.chip, ref.offset


def top_section(api: str = "auto", dead_time_ms: float = 0.0) -> GpiodConfig:
    in1, in2, en = DC
    return make(
        GpiodConfig, api=api, dc={"in1": in1, "in2": in2, "en": en, "dead_time_ms": dead_time_ms}
    )


def axis_section(motor: int, dir_hold_us: float = 0.0) -> GpiodAxisConfig:
    s, d, e, lo, hi = MOTORS[motor]
    return make(
        GpiodAxisConfig,
        step=s,
        dir=d,
        enable=e,
        dir_hold_us=dir_hold_us,
        endstop_min=lo,
        endstop_max=hi,
    )


def pin_section(number: int) -> GpiodPinConfig:
    return make(GpiodPinConfig, line=PINS[number])


#: the tolerance of lag the guest's daemons get (motors[].max_lag_full_steps, its maximum)
GUEST_MAX_LAG = 64.0

#: how long a guest's daemon may take to say READY: two Python processes (the daemon and its
#: step executor) importing the package under TCG, compiling it on the first start of a fresh
#: checkout; measured 30-60 s with the host loaded (the tests' default, 30 s, is for a real CPU)
GUEST_READY_TIMEOUT_S = 180.0


def in_the_guest(example: str, api: str) -> str:
    """docs/examples/raspberry-pi.toml as the tier's daemons run it: the libgpiod API forced,
    no real-time priority, and the widest lag tolerance. The guest is emulated (QEMU TCG,
    no KVM): its step timing says nothing about a board's, and the tier checks what reaches
    the lines, not timing; the lag rule's own tests run in `make test` (docs/timing.md)."""
    text = example.replace("priority = 50 ", "priority = 0  ")
    text = text.replace('api = "auto"', f'api = "{api}"')
    text, n = re.subn(
        r"^(max_speed = [^\n]*)$", rf"\1\nmax_lag_full_steps = {GUEST_MAX_LAG}", text, flags=re.M
    )
    assert n == 3 and "priority = 0 " in text and f'api = "{api}"' in text, "example changed"
    return text


def example_in_the_guest(api: str) -> str:
    """The documented example as the guest runs it (:func:`in_the_guest`), without its
    [motors.tmc] tables (no TMC chip answers in the guest; the SPI side is checked by
    hwtest/spi_wire.py and tests/hal/layers/tmc/test_*.py)."""
    text = re.sub(r"  \[motors\.tmc\][^\n]*\n(  \w+ = [^\n]*\n)*", "", EXAMPLE.read_text())
    assert not re.search(r"^\s*\[motors\.tmc\]|^\s*driver = ", text, re.M)
    return in_the_guest(text, api)
