"""TMC chips on a fake SPI bus: register-level models (tests/support/tmc_model.py) behind
the fake kernel's /dev/spidev0.x, motorctl's own SPI devices and bus locks over it, on a
virtual clock."""

from __future__ import annotations

from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.settings import TmcSettings
from motorctl.hal.layers.tmc.spi import SpiAddress, SpiBuses, SpiDevice
from tests.support.tmc_model import FakeKernel, TmcModel

#: The SPI clock the drivers are opened with (Hz).
SPEED = 4_000_000


class SpiBench:
    """A fake kernel with chips on /dev/spidev0.x and the bus locks."""

    def __init__(self) -> None:
        self.kernel = FakeKernel()
        self.buses = SpiBuses()
        self.clock = VirtualClock()

    def chip(self, kind: str, cs: int = 0, **kw: object) -> TmcModel:
        """A ``kind`` model ("tmc2130", "tmc5160") on chip select ``cs`` of bus 0."""
        model = TmcModel(kind, clock=self.clock, **kw)  # type: ignore[arg-type]
        self.kernel.chips[(0, cs)] = model
        return model

    def device(self, cs: int = 0, bus: int = 0, speed: int = SPEED) -> SpiDevice:
        return SpiDevice(SpiAddress(bus, cs), self.buses, self.kernel.factory(), speed)

    def driver(self, settings: TmcSettings, cs: int = 0) -> TmcDriver:
        return TmcDriver(f"m{cs}", self.device(cs), settings)
