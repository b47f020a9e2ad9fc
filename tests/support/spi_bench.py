"""TMC chips on a fake SPI bus: register-level models (tests/support/tmc_model.py) behind
the fake kernel's /dev/spidev0.x, motorctl's own SPI buses (hal/spi.py) and drivers over
them, on a virtual clock. The ``spi_bench`` fixture (tests/conftest.py) hands one to a test."""

from __future__ import annotations

import sys
import types

import pytest

from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.tmc.config import CHIPS
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.settings import TmcSettings
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, RefSwitches, Tmc5160
from motorctl.hal.spi import SpiAddress, SpiBus, SpiBuses, SpiSettings
from tests.support.tmc_model import FakeKernel, TmcModel

#: The SPI clock the drivers are opened with (Hz).
SPEED = 4_000_000

#: A TMC2130's and a TMC5160's settings with stallGuard set up (500 step/s and faster).
S2130 = TmcSettings(
    chip=TMC2130,
    run_current=0.8,
    hold_current=0.4,
    microsteps=16,
    stall_threshold=5,
    stall_min_speed=500.0,
)
S5160 = TmcSettings(
    chip=TMC5160,
    run_current=2.0,
    hold_current=1.0,
    microsteps=16,
    stall_threshold=-3,
    stall_min_speed=500.0,
)


class SpiBench:
    """A fake kernel with chips on /dev/spidev0.x and the machine's SPI buses."""

    def __init__(self) -> None:
        self.kernel = FakeKernel()
        self.buses = SpiBuses()
        self.clock = VirtualClock()

    def chip(self, kind: str, cs: int = 0, **kw: object) -> TmcModel:
        """A ``kind`` model ("tmc2130", "tmc5160") on chip select ``cs`` of bus 0."""
        model = TmcModel(kind, clock=self.clock, **kw)  # type: ignore[arg-type]
        self.kernel.chips[(0, cs)] = model
        return model

    def device(self, cs: int = 0, bus: int = 0, speed: int = SPEED) -> SpiBus:
        """The bus of /dev/spidev<bus>.<cs> (the same object each time), opened through the
        fake kernel."""
        address = SpiAddress(bus, cs)
        return self.buses.bus(address, SpiSettings(speed), f"test {address}", self.kernel.factory())

    def driver(self, settings: TmcSettings, cs: int = 0) -> TmcDriver:
        """A driver named ``m<cs>``, not started, that names every chip the layer knows."""
        return TmcDriver(f"m{cs}", self.device(cs), settings, CHIPS.values())

    def ramp_driver(self, settings: TmcSettings = S5160) -> tuple[Tmc5160, TmcModel]:
        """A TMC5160 model on chip select 0 and its ramp driver, started (REFL active low)."""
        model = self.chip("tmc5160")
        drv = Tmc5160("x", self.device(), settings, RefSwitches(left_active_low=True))
        drv.start()
        return drv, model

    def as_spidev_module(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Install the fake kernel as the module ``spidev`` for the test: the layer's lazy
        import finds it (the registry builds the layer with py-spidev's factory)."""
        fake = types.SimpleNamespace(SpiDev=self.kernel.factory())
        monkeypatch.setitem(sys.modules, "spidev", fake)
