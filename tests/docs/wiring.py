"""The Raspberry Pi wiring table of the docs, generated from docs/examples/raspberry-pi.toml.

The example is read as the daemon reads it: ``load_config`` (the daemon's loader, every
check of ``motorctld --check-config``), ``hardware_spec`` (what the daemon hands its
backend), then the gpiod backend's own ``wiring_of`` (every line by role) and the TMC
layer's driver specs (each driver's SPI device). What a config does not say comes from the
board: the 40-pin header's pin of each GPIO, SPI0/SPI1's pins, the host UART on GPIO14/15,
and the third chip select of SPI0 from docs/examples/motorctl-spi0-3cs-overlay.dts.

``render()`` is the table with the boot configuration and the notes it needs; it lives
once, in docs/raspberry-pi.md's section 5, between ``BEGIN`` and ``END``, and every other
page that shows wiring points to it. tests/docs/test_wiring.py keeps the page equal to
``render()``; ``python -m tests.docs.wiring --write`` rewrites it, ``--check`` checks it,
``--config FILE`` prints the table of another config (a machine wired otherwise).

Rendering refuses a wiring the board cannot have: a line that is not a header GPIO (by
name: ``GPIO17``, ``ID_SDA``; or ``gpiochip0:17``), a GPIO used twice (the config's lines,
the UART's and the SPI buses' pins together), an SPI device of a bus or chip select the
overlays cannot give.

Pure but for reading the two example files; runs in the caller's thread.
"""

from __future__ import annotations

import argparse
import re
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from motorctl.daemon.config import Config, MotorConfig, load_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.backends.gpiod.config import wiring_of
from motorctl.hal.backends.gpiod.wiring import EndstopWiring, GpioWiring, LineRef, MotorWiring
from motorctl.hal.layers.tmc.settings import TmcSpec
from tests.support import REPO

EXAMPLE: Final = REPO / "docs" / "examples" / "raspberry-pi.toml"
OVERLAY: Final = REPO / "docs" / "examples" / "motorctl-spi0-3cs-overlay.dts"
PAGE: Final = REPO / "docs" / "raspberry-pi.md"
#: the heading of the page's section that holds the table, and its anchor (GitHub's slug)
SECTION: Final = "## 5. Wiring the example machine"
ANCHOR: Final = "raspberry-pi.md#5-wiring-the-example-machine"
BEGIN: Final = (
    "<!-- generated from docs/examples/raspberry-pi.toml by `python -m tests.docs.wiring "
    "--write` (tests/docs/wiring.py); edit the example, not this table -->"
)
END: Final = "<!-- end of the generated wiring -->"

#: BCM GPIO -> pin of the 40-pin header (every Raspberry Pi since the B+, the Pi 5 too)
HEADER_PIN: Final = {
    0: 27, 1: 28, 2: 3, 3: 5, 4: 7, 5: 29, 6: 31, 7: 26, 8: 24, 9: 21,
    10: 19, 11: 23, 12: 32, 13: 33, 14: 8, 15: 10, 16: 36, 17: 11, 18: 12, 19: 35,
    20: 38, 21: 40, 22: 15, 23: 16, 24: 18, 25: 22, 26: 37, 27: 13,
}  # fmt: skip
POWER: Final = {"3.3 V": (1, 17), "5 V": (2, 4), "GND": (6, 9, 14, 20, 25, 30, 34, 39)}
#: the header lines whose name is not GPIOn on Raspberry Pi OS and on a Pi 5 (gpioinfo)
NAMED: Final = {"ID_SDA": 0, "ID_SCL": 1}
#: the names Debian's own kernel (the mainline device tree of a Pi 4) gives header lines
MAINLINE_NAMES: Final = {
    2: "SDA1", 3: "SCL1", 4: "GPIO_GCLK", 7: "SPI_CE1_N", 8: "SPI_CE0_N", 9: "SPI_MISO",
    10: "SPI_MOSI", 11: "SPI_SCLK", 14: "TXD1", 15: "RXD1",
}  # fmt: skip
#: what the board itself does with a line the config may use
BOARD_NOTES: Final = {
    0: "the HAT ID EEPROM's line (ID_SDA): free when no HAT with an EEPROM is fitted",
    1: "the HAT ID EEPROM's line (ID_SCL): free when no HAT with an EEPROM is fitted",
    2: "1.8 kOhm pull-up to 3.3 V on the board: reads high when open",
    3: "1.8 kOhm pull-up to 3.3 V on the board: reads high when open",
}
#: functions of the boot configuration that would take a line away from the config
TAKEN_BY: Final = (
    ((0, 1), "I2C0 (`dtparam=i2c_vc=on`)"),
    ((2, 3), "I2C1 (`dtparam=i2c_arm=on`, raspi-config's I2C)"),
    ((4,), "1-Wire (`dtoverlay=w1-gpio`, whose default line is GPIO4)"),
    ((12, 13, 18, 19), "PWM (`dtoverlay=pwm`, `dtoverlay=pwm-2chan`)"),
    ((18, 19, 20, 21), "I2S (`dtparam=i2s=on`, sound-card overlays)"),
)
#: the host link: UART0 on GPIO14/15 (docs/raspberry-pi.md, section 2)
UART: Final = ((14, "host UART TXD", "the host's RX"), (15, "host UART RXD", "the host's TX"))
OVERLAY_NAME: Final = "motorctl-spi0-3cs"


@dataclass(frozen=True)
class SpiBus:
    """An SPI controller on the header: its pins and how many chip selects each overlay
    gives (``overlays[n - 1]``: the boot configuration line for n chip selects)."""

    sclk: int
    mosi: int
    miso: int
    chip_selects: tuple[int, ...]
    overlays: tuple[str, ...]


def spi_buses() -> dict[int, SpiBus]:
    """SPI0 (``dtparam=spi=on``: CE0, CE1; the overlay of this folder: CE2 as well) and
    SPI1 (``spi1-1cs`` .. ``spi1-3cs``)."""
    return {
        0: SpiBus(
            11,
            10,
            9,
            overlay_chip_selects(OVERLAY.read_text(encoding="utf-8")),
            ("dtparam=spi=on", "dtparam=spi=on", f"dtoverlay={OVERLAY_NAME}"),
        ),
        1: SpiBus(
            21,
            20,
            19,
            (18, 17, 16),
            ("dtoverlay=spi1-1cs", "dtoverlay=spi1-2cs", "dtoverlay=spi1-3cs"),
        ),
    }


def overlay_chip_selects(dts: str) -> tuple[int, ...]:
    """The chip-select GPIOs of the SPI0 overlay (its ``cs-gpios``), checked against the
    pins it sets as outputs (``brcm,pins``) and its spidev devices (one per chip select
    past the two the base device tree has)."""
    cs = tuple(int(n) for n in re.findall(r"<&gpio (\d+) \d+>", _one(r"cs-gpios = ([^;]+);", dts)))
    pins = tuple(int(n) for n in _one(r"brcm,pins = <([\d ]+)>;", dts).split())
    regs = sorted(int(n) for n in re.findall(r"spidev@\d+ \{[^}]*?reg = <(\d+)>", dts, re.S))
    if cs != pins or regs != list(range(2, len(cs))):
        raise ValueError(f"{OVERLAY.name}: cs-gpios {cs}, brcm,pins {pins}, spidev regs {regs}")
    return cs


def _one(pattern: str, text: str) -> str:
    found = re.findall(pattern, text)
    if len(found) != 1:
        raise ValueError(f"{OVERLAY.name}: {pattern!r} found {len(found)} times")
    return str(found[0])


class WiringError(ValueError):
    """The example asks for a wiring the header cannot have (what, in the message)."""


def gpio_of(ref: LineRef) -> int:
    """The BCM number of a header line as the config names it."""
    if ref.name is not None:
        if ref.name in NAMED:
            return NAMED[ref.name]
        m = re.fullmatch(r"GPIO(\d+)", ref.name)
        if m and int(m.group(1)) in HEADER_PIN:
            return int(m.group(1))
    elif ref.chip == "gpiochip0" and ref.offset in HEADER_PIN:
        return ref.offset
    raise WiringError(f"{ref} is not a line of the 40-pin header (GPIO0..GPIO27, ID_SDA, ID_SCL)")


@dataclass(frozen=True)
class Row:
    """One line of the table: what, which GPIO (None: power or not wired), where it goes;
    ``line``: the line as the config names it ("" for the board's own: UART, SPI);
    ``pins``: header pins of a supply."""

    what: str
    gpio: int | None
    to: str
    line: str = ""
    pins: tuple[int, ...] = ()

    @property
    def named(self) -> str:
        """The config's name of the line when it is not GPIOn (``ID_SDA``)."""
        return "" if re.fullmatch(r"GPIO\d+|", self.line) else self.line


@dataclass(frozen=True)
class Wiring:
    """Everything the table says: its rows and what the boot configuration needs."""

    rows: tuple[Row, ...]
    boot: tuple[str, ...]

    def used(self) -> dict[int, str]:
        """GPIO -> what it is for; WiringError for a GPIO used twice."""
        seen: dict[int, str] = {}
        for row in self.rows:
            if row.gpio is None:
                continue
            if row.gpio in seen:
                raise WiringError(f"GPIO{row.gpio} is both {seen[row.gpio]} and {row.what}")
            seen[row.gpio] = row.what
        return seen

    def roles(self) -> dict[str, int | None]:
        """role (``motor x STEP``, ``pin 6``, ``SPI0 CE2`` ...) -> GPIO, as the table has it."""
        return {row.what: row.gpio for row in self.rows if not row.pins}


def _spi_device(path: str) -> tuple[int, int]:
    m = re.fullmatch(r"/dev/spidev(\d+)\.(\d+)", path)
    if m is None:
        raise WiringError(f"{path} is not an SPI device /dev/spidevB.C")
    return int(m.group(1)), int(m.group(2))


def _end_stop(es: EndstopWiring, active_low: bool) -> str:
    pull = {"pull-up": "pull-up on", "pull-down": "pull-down on"}.get(es.bias, "no pull set by")
    level = "low" if active_low else "high"
    return f"a switch (triggered reads {level}; {pull} the line)"


def wiring(config: Config | None = None) -> Wiring:
    """The table's content for ``config`` (the example by default), read as the daemon
    reads it."""
    config = config if config is not None else load_config(EXAMPLE)
    spec = hardware_spec(config)
    gpio: GpioWiring = wiring_of(spec)
    buses = spi_buses()
    selects: dict[int, list[int]] = {}  # bus -> the chip selects in use
    motor_rows: list[Row] = []
    for i, (axis, m, mc) in enumerate(zip(spec.axes, gpio.motors, config.motors, strict=True)):
        driver = axis.driver if isinstance(axis.driver, TmcSpec) else None
        who = f"motor {i} ({axis.name})"
        if driver is not None:
            bus, cs = _spi_device(driver.spi)
            if bus not in buses or cs >= len(buses[bus].chip_selects):
                raise WiringError(f"{who}: {driver.spi}: no overlay gives SPI{bus} CE{cs}")
            selects.setdefault(bus, []).append(cs)
        motor_rows += _motor_rows(who, m, mc, driver, buses)
    rows = [Row(what, n, to) for n, what, to in UART]
    for bus in sorted(selects):
        b = buses[bus]
        every = "every driver's" if len(selects[bus]) > 1 else "the driver's"
        rows += [
            Row(f"SPI{bus} SCLK", b.sclk, f"{every} SCK"),
            Row(f"SPI{bus} MOSI", b.mosi, f"{every} SDI"),
            Row(f"SPI{bus} MISO", b.miso, f"{every} SDO"),
        ]
    rows += motor_rows + _bridge_rows(gpio) + _pin_rows(gpio, config)
    rows += [
        Row("3.3 V", None, "the drivers' VIO (logic supply)", pins=POWER["3.3 V"]),
        Row("GND", None, "the host's, every driver's and the bridge's GND", pins=POWER["GND"]),
        Row("5 V", None, "no logic input: the GPIOs are not 5 V tolerant", pins=POWER["5 V"]),
    ]
    boot = ["enable_uart=1", *(buses[bus].overlays[max(cs)] for bus, cs in sorted(selects.items()))]
    if gpio.dc is not None and gpio.dc.pwm is not None:
        boot.append("dtoverlay=pwm")
    result = Wiring(tuple(rows), tuple(boot))
    result.used()  # no GPIO twice
    return result


def _motor_rows(
    who: str, m: MotorWiring, mc: MotorConfig, driver: TmcSpec | None, buses: dict[int, SpiBus]
) -> list[Row]:
    """A motor's chip select, STEP, DIR, EN and end stops."""
    rows = []
    chip = driver.settings.chip.name if driver is not None else "driver"
    if driver is not None:
        bus, cs = _spi_device(driver.spi)
        pin = buses[bus].chip_selects[cs]
        rows.append(Row(f"{who} chip select, SPI{bus} CE{cs}", pin, f"{chip} CSN ({driver.spi})"))
    for role, ref in (("STEP", m.step), ("DIR", m.dir)):
        if ref is not None:
            rows.append(Row(f"{who} {role}", gpio_of(ref), f"{chip} {role}", str(ref)))
    if m.enable is not None:
        on = "low" if m.enable_active_low else "high"
        rows.append(Row(f"{who} EN", gpio_of(m.enable), f"{chip} EN (on: {on})", str(m.enable)))
    else:
        rows.append(Row(f"{who} EN", None, f"{chip} EN tied to GND (always enabled)"))
    for which, es in (("min", m.endstop_min), ("max", m.endstop_max)):
        if es is not None:
            to = _end_stop(es, mc.endstop.active_low)
            rows.append(Row(f"{who} end stop {which}", gpio_of(es.line), to, str(es.line)))
    return rows


def _bridge_rows(gpio: GpioWiring) -> list[Row]:
    d = gpio.dc
    if d is None:
        return []
    rows = [
        Row("DC motor IN1", gpio_of(d.in1), "H-bridge IN1", str(d.in1)),
        Row("DC motor IN2", gpio_of(d.in2), "H-bridge IN2", str(d.in2)),
    ]
    if d.en is not None:
        rows.append(Row("DC motor EN", gpio_of(d.en), "H-bridge EN", str(d.en)))
    elif d.pwm is None:
        rows.append(Row("DC motor EN", None, "H-bridge EN tied high"))
    return rows


def _pin_rows(gpio: GpioWiring, config: Config) -> list[Row]:
    rows = []
    for p, pc in zip(gpio.pins, config.pins, strict=True):
        if pc.is_output:
            what = f"output, {_level(pc.initial)} at start, {_level(pc.safe)} at exit"
        else:
            what = "input" + ("" if p.bias == "as-is" else f", {p.bias}")
        rows.append(Row(f"pin {p.number}", gpio_of(p.line), what, str(p.line)))
    return rows


def _level(high: bool) -> str:
    return "high" if high else "low"


def _gpio_cell(row: Row) -> str:
    if row.gpio is None:
        return "-"
    return f"GPIO{row.gpio}" + (f" (`{row.named}`)" if row.named else "")


def _pin_cell(row: Row) -> str:
    if row.pins:
        return ", ".join(map(str, row.pins))
    return "-" if row.gpio is None else str(HEADER_PIN[row.gpio])


BOOT_COMMENTS: Final = {
    "enable_uart=1": "the host UART on GPIO14/15, with section 2's lines",
    "dtparam=spi=on": "SPI0 with CE0 and CE1 (section 3)",
    f"dtoverlay={OVERLAY_NAME}": "SPI0 with CE0, CE1 and CE2 (section 3)",
    "dtoverlay=pwm": "the bridge's EN as a PWM channel",
}


def render(w: Wiring | None = None) -> str:
    """The generated block (without its markers): the table, the boot configuration and
    the notes the example's lines need."""
    w = w if w is not None else wiring()
    used = w.used()
    lines = [
        "| function | GPIO | header pin | to |",
        "|---|---|---|---|",
        *(f"| {r.what} | {_gpio_cell(r)} | {_pin_cell(r)} | {r.to} |" for r in w.rows),
        "",
        "In `/boot/firmware/config.txt` (then reboot):",
        "",
        "```ini",
        *(f"{b:<30} # {BOOT_COMMENTS.get(b, '')}".rstrip(" #") for b in w.boot),
        "```",
        "",
    ]
    notes = []
    for gpio, note in sorted(BOARD_NOTES.items()):
        if gpio in used:
            notes.append(f"GPIO{gpio}, {used[gpio]}: {note}.")
    taken = [what for gpios, what in TAKEN_BY if any(g in used for g in gpios)]
    if taken:
        notes.append("Leave off what would take these lines: " + "; ".join(taken) + ".")
    free = [f"GPIO{g}" for g in sorted(HEADER_PIN) if g not in used]
    notes.append(
        "Free header lines: "
        + (
            ", ".join(free)
            if free
            else "none (an ENABLE line per driver needs one taken from the pins)"
        )
        + "."
    )
    renamed = [
        f"`GPIO{r.gpio}` is `{MAINLINE_NAMES[r.gpio]}`"
        for r in sorted(w.rows, key=lambda r: r.gpio or 0)
        if r.gpio in MAINLINE_NAMES and r.line == f"GPIO{r.gpio}"
    ]
    if renamed:
        notes.append(
            "Debian's own kernel (its raspi images, the mainline device tree) names some of "
            "these lines after the board's schematic: " + ", ".join(renamed) + "; write those "
            "names there (`gpioinfo` lists them)."
        )
    lines += [textwrap.fill(n, 92, initial_indent="- ", subsequent_indent="  ") for n in notes]
    return "\n".join(lines) + "\n"


def block(page_text: str) -> str:
    """The generated block of a page, between its markers (ValueError: none or several)."""
    if page_text.count(BEGIN) != 1 or page_text.count(END) != 1:
        raise ValueError("the page does not hold the generated wiring exactly once")
    return page_text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n") + "\n"


def write(page: Path = PAGE) -> bool:
    """Put ``render()`` between the page's markers; True when that changed it."""
    text = page.read_text(encoding="utf-8")
    old = block(text)
    new = render()
    if old == new:
        return False
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    page.write_text(f"{head}{BEGIN}\n{new}{END}{tail}", encoding="utf-8")
    return True


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true", help=f"rewrite the table in {PAGE}")
    p.add_argument("--check", action="store_true", help=f"exit 1 if {PAGE}'s table is stale")
    p.add_argument("--config", type=Path, help="print the table of this config instead")
    args = p.parse_args(argv)
    if args.config is not None:
        sys.stdout.write(render(wiring(load_config(args.config))))
    elif args.write:
        write()
    elif args.check:
        if block(PAGE.read_text(encoding="utf-8")) != render():
            print(f"{PAGE}: the wiring table is stale: run python -m tests.docs.wiring --write")
            return 1
    else:
        sys.stdout.write(render())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
