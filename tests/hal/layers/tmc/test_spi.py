"""The SPI bus (spi.py): the fake py-spidev keeps py-spidev's contract, devices are named by
bus and chip select, a missing or refused device or a missing py-spidev is an error that
says the fix, and one lock per bus keeps pipelined reads whole across threads."""

from __future__ import annotations

import errno
import threading

import pytest

from motorctl.hal.interfaces import HalError
from motorctl.hal.layers.tmc.link import TmcLink
from motorctl.hal.layers.tmc.spi import SpiAddress, SpiError
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, Reg
from tests.support.spi_bench import S2130, SpiBench
from tests.support.tmc_model import FakeSpiDev


def test_fake_spidev_keeps_py_spidevs_contract(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130")
    dev = FakeSpiDev(spi_bench.kernel)
    with pytest.raises(OSError) as e:
        dev.mode = 3  # before open: the ioctl fails on fd -1
    assert e.value.errno == errno.EBADF
    with pytest.raises(OSError) as e:
        dev.open(0, 7)
    assert e.value.errno == errno.ENOENT
    dev.open(0, 0)
    dev.mode = 3
    buf = [0x04, 0, 0, 0, 0]
    out = dev.xfer2(buf)
    assert out is buf  # xfer2 writes the received bytes into the list it was given
    assert buf[0] & 0x01  # reset_flag after power-up, in the status byte


def test_spi_address_parsing() -> None:
    assert SpiAddress.parse("/dev/spidev1.2") == SpiAddress(1, 2)
    assert SpiAddress.parse("0.1").path == "/dev/spidev0.1"
    with pytest.raises(ValueError, match=r"/dev/spidevB.C"):
        SpiAddress.parse("/dev/ttyAMA0")


def test_missing_device_names_the_path_and_the_fix(spi_bench: SpiBench) -> None:
    with pytest.raises(SpiError) as e:
        spi_bench.driver(S2130, cs=1).start()
    assert "/dev/spidev0.1 does not exist" in str(e.value)
    assert "dtparam=spi=on" in str(e.value)


def test_permission_denied_names_the_group(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130")
    spi_bench.kernel.no_permission.add((0, 0))
    with pytest.raises(SpiError, match=r"no permission to open /dev/spidev0.0.*usermod -aG spi"):
        spi_bench.driver(S2130).start()


def test_spidev_missing_is_a_hal_error_saying_how_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import builtins

    from motorctl.hal.layers.tmc.spi import spidev_factory

    real_import = builtins.__import__

    def no_spidev(name: str, *args: object, **kw: object) -> object:
        if name == "spidev":
            raise ImportError("No module named 'spidev'")
        return real_import(name, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_spidev)
    with pytest.raises(HalError, match="python3-spidev"):
        spidev_factory()


def test_one_bus_lock_keeps_pipelined_reads_whole_across_threads(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130", cs=0)
    spi_bench.chip("tmc5160", cs=1, sd_mode=1)
    a, b = spi_bench.device(0), spi_bench.device(1)
    assert a.lock is b.lock  # one bus, one lock
    assert spi_bench.device(0, bus=1).lock is not a.lock
    a.open()
    b.open()
    links = [TmcLink(a, TMC2130), TmcLink(a, TMC2130), TmcLink(b, TMC5160)]
    wrong: list[str] = []

    def reader(link: TmcLink) -> None:
        for _ in range(300):
            got = link.read(Reg.IOIN) >> 24
            if got != link.chip.version:
                wrong.append(f"{link.chip.name}: 0x{got:02x}")

    threads = [threading.Thread(target=reader, args=(lk,)) for lk in links]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30.0)
        assert not t.is_alive(), "a reader did not finish within 30 s"
    assert wrong == []
