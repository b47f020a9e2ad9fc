"""Which gpio-sim lines the tier wires to what (the VM has hwtest.gsim.BANKS/NAMES).

The motors, end stops, bridge and pins of docs/examples/raspberry-pi.toml use the Raspberry
Pi's line names (GPIO17 ...), which gpio-sim's bank 0 carries too; the contract tests add
ENABLE lines as chip:offset and max end stops by name on the second chip, to cover every
way of naming a line.
"""

from __future__ import annotations

from motorctl.hal.wiring import (
    DcWiring,
    EndstopWiring,
    GpioWiring,
    LineRef,
    MotorWiring,
    PinWiring,
)

#: step, dir, enable, min, max
MOTORS = [
    ("GPIO17", "GPIO27", "gpiochip0:28", "GPIO26", "B1_4"),
    ("GPIO22", "GPIO23", "gpiochip0:29", "GPIO16", "B1_5"),
    ("GPIO5", "GPIO6", "gpiochip0:30", "GPIO20", "B1_6"),
]
DC = ("GPIO13", "GPIO19", "GPIO21")  # IN1, IN2, EN
PINS = ["GPIO4", "GPIO25", "GPIO18", "GPIO12", "GPIO2", "GPIO3", "GPIO0", "GPIO1"]


def where(text: str) -> tuple[str, int]:
    """The sim chip and offset of a line as this layout writes it."""
    ref = LineRef.parse(text)
    if ref.name is not None:
        if ref.name.startswith("GPIO"):
            return "gpiochip0", int(ref.name[4:])
        if ref.name.startswith("B1_"):
            return "gpiochip1", int(ref.name[3:])
        raise LookupError(text)
    assert ref.chip is not None and ref.offset is not None
    return ref.chip, ref.offset


def wiring(motors: int, pins: list[int], dc: bool, api: str = "auto",
           dead_time_ms: float = 0.0, dir_hold_us: float = 0.0) -> GpioWiring:
    mw = tuple(
        MotorWiring(
            step=LineRef.parse(s), dir=LineRef.parse(d), enable=LineRef.parse(e),
            endstop_min=EndstopWiring(LineRef.parse(lo)),
            endstop_max=EndstopWiring(LineRef.parse(hi)),
            dir_hold_us=dir_hold_us,
        )
        for s, d, e, lo, hi in MOTORS[:motors]
    )
    in1, in2, en = (LineRef.parse(x) for x in DC)
    dcw = DcWiring(in1, in2, en, dead_time_ms=dead_time_ms) if dc else None
    return GpioWiring(api=api, motors=mw, dc=dcw,
                      pins=tuple(PinWiring(n, LineRef.parse(PINS[n])) for n in pins))
