"""Real boards' GPIO chip layouts, made on gpio-sim inside the test VM (`hwtest/run layouts`).

Each layout has the chips a Raspberry Pi kernel shows: the same labels, line counts, line
names and chip numbers (the numbers are the kernel's to give: lower ones are taken by
short-lived one-line padding chips, which are removed once the board's chips are live, so
a layout can start at gpiochip4 or gpiochip11 as real kernels do). Where they come from:

- Raspberry Pi 4: Raspberry Pi OS kernels (6.6, 6.12): gpiochip0 [pinctrl-bcm2711] 58
  lines, ID_SDA, ID_SCL, GPIO2..GPIO27, then the SoC's own uses; gpiochip1
  [raspberrypi-exp-gpio] 8 lines. (Debian's own kernel uses mainline's device tree, which
  names the header lines after the schematic: SDA1, SPI_CE0_N, TXD1 ...; a config for it
  writes ``pinctrl-bcm2711:17``.)
- Raspberry Pi 5 before kernel 6.6.45: the SoC's four gpio-brcmstb chips gpiochip0..3, the
  RP1's pinctrl-rp1 (54 lines, the header) gpiochip4.
- Raspberry Pi 5, 6.6.45 and later (raspberrypi/linux#6144): pinctrl-rp1 gpiochip0, the
  SoC's chips gpiochip10..13, and Raspberry Pi OS's udev link /dev/gpiochip4 -> gpiochip0.
- Raspberry Pi 5, kernels of 2026 (6.12.96+rpt, Adafruit_Blinka#1119): gpiochip11..15 and
  nothing below; the report does not say which is the RP1: here the last, gpiochip15, so that
  nothing which picks the lowest or a fixed number finds it.

Owned by the one test process that builds a layout (configfs and /dev are global); blocks
only on sysfs/configfs file I/O.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

CONFIGFS = "/sys/kernel/config/gpio-sim"


def _header(tail: Sequence[str]) -> tuple[str, ...]:
    """A Raspberry Pi header chip's names: ID_SDA, ID_SCL, GPIO2..GPIO27, then ``tail``."""
    return ("ID_SDA", "ID_SCL", *(f"GPIO{n}" for n in range(2, 28)), *tail)


BCM2711 = _header(
    (
        "RGMII_MDIO",
        "RGMIO_MDC",
        "CTS0",
        "RTS0",
        "TXD0",
        "RXD0",
        "SD1_CLK",
        "SD1_CMD",
        "SD1_DATA0",
        "SD1_DATA1",
        "SD1_DATA2",
        "SD1_DATA3",
        "PWM0_MISO",
        "PWM1_MOSI",
        "STATUS_LED_G_CLK",
        "SPIFLASH_CE_N",
        "SDA0",
        "SCL0",
        "RGMII_RXCLK",
        "RGMII_RXCTL",
        "RGMII_RXD0",
        "RGMII_RXD1",
        "RGMII_RXD2",
        "RGMII_RXD3",
        "RGMII_TXCLK",
        "RGMII_TXCTL",
        "RGMII_TXD0",
        "RGMII_TXD1",
        "RGMII_TXD2",
        "RGMII_TXD3",
    )
)
EXP_GPIO = (
    "BT_ON",
    "WL_ON",
    "PWR_LED_OFF",
    "GLOBAL_RESET",
    "VDD_SD_IO_SEL",
    "CAM_GPIO",
    "SD_PWR_ON",
    "",
)
RP1 = _header(
    (
        "PCIE_RP1_WAKE",
        "FAN_TACH",
        "HOST_SDA",
        "HOST_SCL",
        "ETH_RST_N",
        "-",
        "CD0_IO0_MICCLK",
        "CD0_IO0_MICDAT0",
        "RP1_PCIE_CLKREQ_N",
        "-",
        "CD0_SDA",
        "CD0_SCL",
        "CD1_SDA",
        "CD1_SCL",
        "USB_VBUS_EN",
        "USB_OC_N",
        "RP1_STAT_LED",
        "FAN_PWM",
        "CD1_IO0_MICCLK",
        "2712_WAKE",
        "CD1_IO1_MICDAT1",
        "EN_MAX_USB_CUR",
        "-",
        "-",
        "-",
        "-",
    )
)


def _named(count: int, names: dict[int, str]) -> tuple[str, ...]:
    """``count`` lines, named where ``names`` says, "-" elsewhere (as the kernel shows them)."""
    return tuple(names.get(offset, "-") for offset in range(count))


#: the Pi 5 SoC's own chips (label, line names)
BRCMSTB = (
    (
        "gpio-brcmstb@107d508500",
        _named(
            32,
            {
                1: "2712_BOOT_CS_N",
                2: "2712_BOOT_MISO",
                3: "2712_BOOT_MOSI",
                4: "2712_BOOT_SCLK",
                14: "PCIE_SDA",
                15: "PCIE_SCL",
                20: "PWR_GPIO",
                21: "2712_G21_FS",
                24: "BT_RTS",
                25: "BT_CTS",
                26: "BT_TXD",
                27: "BT_RXD",
                28: "WL_ON",
                29: "BT_ON",
                30: "WIFI_SDIO_CLK",
                31: "WIFI_SDIO_CMD",
            },
        ),
    ),
    ("gpio-brcmstb@107d508520", tuple(f"WIFI_SDIO_D{n}" for n in range(4))),
    (
        "gpio-brcmstb@107d517c00",
        _named(
            17,
            {
                0: "RP1_SDA",
                1: "RP1_SCL",
                2: "RP1_RUN",
                3: "SD_IOVDD_SEL",
                4: "SD_PWR_ON",
                5: "SD_CDET_N",
                6: "SD_FLG_N",
                8: "2712_WAKE",
                9: "2712_STAT_LED",
                12: "PMIC_INT",
                13: "UART_TX_FS",
                14: "UART_RX_FS",
            },
        ),
    ),
    (
        "gpio-brcmstb@107d517c20",
        ("HDMI0_SCL", "HDMI0_SDA", "HDMI1_SCL", "HDMI1_SDA", "PMIC_SCL", "PMIC_SDA"),
    ),
)


@dataclass(frozen=True)
class SimChip:
    number: int  # gpiochipN
    label: str
    names: tuple[str, ...]  # one per line; "" = unnamed


@dataclass(frozen=True)
class Board:
    key: str  # hwtest/run layouts' name for it
    title: str
    chips: tuple[SimChip, ...]
    header: str  # the label of the chip that carries the 40-pin header
    links: dict[str, str] = field(default_factory=dict)  # /dev/NAME -> gpiochipN
    #: what `motorctld --probe` says of the layout
    layout: str = ""

    def chip(self, label: str) -> SimChip:
        (chip,) = [c for c in self.chips if c.label == label]
        return chip


def _soc(first: int) -> tuple[SimChip, ...]:
    return tuple(SimChip(first + i, label, names) for i, (label, names) in enumerate(BRCMSTB))


_PI5 = "Raspberry Pi 5 / 500 / CM5 (RP1): the header's lines are "
BOARDS: tuple[Board, ...] = (
    Board(
        "pi4",
        "Raspberry Pi 4 (Raspberry Pi OS kernel)",
        (SimChip(0, "pinctrl-bcm2711", BCM2711), SimChip(1, "raspberrypi-exp-gpio", EXP_GPIO)),
        "pinctrl-bcm2711",
        layout="Raspberry Pi 4 / 400 / CM4 (BCM2711): the header's lines are gpiochip0 "
        "[pinctrl-bcm2711] 58 lines",
    ),
    Board(
        "pi5-gpiochip4",
        "Raspberry Pi 5, kernel before 6.6.45",
        (*_soc(0), SimChip(4, "pinctrl-rp1", RP1)),
        "pinctrl-rp1",
        layout=_PI5 + "gpiochip4 [pinctrl-rp1] 54 lines (RP1 as gpiochip4, as kernels "
        "before 6.6.45 number it)",
    ),
    Board(
        "pi5-gpiochip0",
        "Raspberry Pi 5, kernel 6.6.45 and later (with Raspberry Pi OS's gpiochip4 link)",
        (SimChip(0, "pinctrl-rp1", RP1), *_soc(10)),
        "pinctrl-rp1",
        links={"gpiochip4": "gpiochip0"},
        layout=_PI5 + "gpiochip0 [pinctrl-rp1] 54 lines (RP1 as gpiochip0, as kernels 6.6.45 "
        "and later number it)",
    ),
    Board(
        "pi5-2026",
        "Raspberry Pi 5, kernel of 2026 (6.12.96+rpt: gpiochip10 and up only)",
        (*_soc(11), SimChip(15, "pinctrl-rp1", RP1)),
        "pinctrl-rp1",
        layout=_PI5 + "gpiochip15 [pinctrl-rp1] 54 lines (no chip below gpiochip10, as "
        "kernels of 2026 (6.12.96+rpt) number them)",
    ),
)


def board(key: str) -> Board:
    (found,) = [b for b in BOARDS if b.key == key]
    return found


def _write(path: str, value: object) -> None:
    with open(path, "w") as f:
        f.write(str(value))


def _read(path: str) -> str:
    with open(path) as f:
        return f.read().strip()


def chip_numbers() -> list[int]:
    """The gpiochipN numbers the kernel has now (links not counted)."""
    out = []
    for name in os.listdir("/dev"):
        tail = name[len("gpiochip") :]
        if name.startswith("gpiochip") and tail.isdigit() and not os.path.islink(f"/dev/{name}"):
            out.append(int(tail))
    return sorted(out)


class SimDevice:
    """One gpio-sim device (configfs), one bank = one chip, live until :meth:`remove`."""

    def __init__(self, name: str, label: str, names: Sequence[str]) -> None:
        self.dir = f"{CONFIGFS}/{name}"
        os.mkdir(self.dir)
        bank = f"{self.dir}/bank0"
        os.mkdir(bank)
        _write(f"{bank}/num_lines", len(names))
        _write(f"{bank}/label", label)
        for offset, line_name in enumerate(names):
            if line_name:
                os.mkdir(f"{bank}/line{offset}")
                _write(f"{bank}/line{offset}/name", line_name)
        _write(f"{self.dir}/live", 1)
        self.chip = _read(f"{bank}/chip_name")
        self.dev = _read(f"{self.dir}/dev_name")

    def remove(self) -> None:
        _write(f"{self.dir}/live", 0)
        bank = f"{self.dir}/bank0"
        for entry in os.listdir(bank):
            if entry.startswith("line"):
                os.rmdir(f"{bank}/{entry}")
        os.rmdir(bank)
        os.rmdir(self.dir)


@contextmanager
def built(b: Board) -> Iterator[dict[str, SimDevice]]:
    """The board's chips live on gpio-sim with its numbers and /dev links; by label. Needs
    a guest without other GPIO chips (hwtest/run layouts boots it so)."""
    if chip_numbers():
        raise RuntimeError(f"other GPIO chips exist: {chip_numbers()}")
    devices: dict[str, SimDevice] = {}
    padding: list[SimDevice] = []
    try:
        for i, chip in enumerate(sorted(b.chips, key=lambda c: c.number)):
            while (chip_numbers() or [-1])[-1] + 1 < chip.number:
                padding.append(SimDevice(f"pad{len(padding)}", "padding", [""]))
            d = SimDevice(f"{b.key}-{i}", chip.label, chip.names)
            assert d.chip == f"gpiochip{chip.number}", (d.chip, chip)
            devices[chip.label] = d
        for d in padding:
            d.remove()
        padding.clear()
        for link, target in b.links.items():
            os.symlink(target, f"/dev/{link}")
        assert chip_numbers() == sorted(c.number for c in b.chips), chip_numbers()
        yield devices
    finally:
        for link in b.links:
            if os.path.islink(f"/dev/{link}"):
                os.unlink(f"/dev/{link}")
        for d in [*padding, *devices.values()]:
            d.remove()


def available() -> bool:
    """gpio-sim's configfs is there (the guests of hwtest/run)."""
    return os.path.isdir(CONFIGFS)
