"""The SPI buses (spi.py): the fake py-spidev keeps py-spidev's contract, devices are named by
bus and chip select, a missing or refused device or a missing py-spidev is an error that
says the fix; one bus per device node, shared by its users and refused to one that needs
other settings, opened until its last user closes it; one lock per node keeps a pipelined
read, and a daisy chain's exchange of several transfers, whole across threads."""

from __future__ import annotations

import errno
import threading

import pytest

from motorctl.hal.interfaces import HalError
from motorctl.hal.layers.tmc.link import TmcLink
from motorctl.hal.layers.tmc.tmc2130 import TMC2130
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, Reg
from motorctl.hal.spi import SpiAddress, SpiBuses, SpiError, SpiSettings, spidev_factory
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
    dev.bits_per_word = 8
    with pytest.raises(TypeError):
        dev.bits_per_word = 7
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

    real_import = builtins.__import__

    def no_spidev(name: str, *args: object, **kw: object) -> object:
        if name == "spidev":
            raise ImportError("No module named 'spidev'")
        return real_import(name, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_spidev)
    with pytest.raises(HalError, match="python3-spidev"):
        spidev_factory()


def test_one_lock_per_node_keeps_pipelined_reads_whole_across_threads(
    spi_bench: SpiBench,
) -> None:
    spi_bench.chip("tmc2130", cs=0)
    spi_bench.chip("tmc5160", cs=1, sd_mode=1)
    a, b = spi_bench.device(0), spi_bench.device(1)
    assert spi_bench.device(0) is a  # one bus per node, whoever asks
    assert a.lock is not b.lock  # chip selects of one controller: no lock between them
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


def test_a_node_is_one_bus_in_one_setting_for_all_its_users(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130", cs=0)
    buses = SpiBuses()
    factory = spi_bench.kernel.factory()
    node = SpiAddress(0, 0)
    chain = buses.bus(node, SpiSettings(4_000_000), "chain (3 chips)", factory)
    assert buses.bus(node, SpiSettings(4_000_000), "another user", factory) is chain
    assert chain.users == ["chain (3 chips)", "another user"]
    with pytest.raises(SpiError) as e:
        buses.bus(node, SpiSettings(1_000_000, mode=0), "x (TMC2130)", factory)
    text = str(e.value)
    assert text.startswith("/dev/spidev0.0: x (TMC2130) needs mode 0, 1000000 Hz, 8-bit words")
    assert "chain (3 chips), another user on the same chip select needs mode 3, 4000000 Hz" in text
    other = buses.bus(SpiAddress(0, 1), SpiSettings(1_000_000, mode=0), "y", factory)
    assert other is not chain and other.settings.mode == 0  # its own chip select, own setting
    assert [b.path for b in buses] == ["/dev/spidev0.0", "/dev/spidev0.1"]


def test_a_node_opens_in_its_settings_and_closes_with_its_last_user(spi_bench: SpiBench) -> None:
    spi_bench.chip("tmc2130", cs=0)
    bus = spi_bench.device(0, speed=2_000_000)
    bus.open()
    bus.open()  # a second user of the node: the same descriptor
    (dev,) = spi_bench.kernel.opened
    assert (dev.mode, dev.bits_per_word, dev.max_speed_hz) == (3, 8, 2_000_000)
    bus.close()
    assert bus.is_open and dev._fd != -1  # the other user still has it
    bus.close()
    assert not bus.is_open and dev._fd == -1
    bus.close()  # one close too many does nothing
    with pytest.raises(SpiError, match=r"/dev/spidev0.0 is not open"):
        bus.xfer(b"\x00" * 5)


def test_a_daisy_chain_exchange_holds_its_node_between_its_transfers(
    spi_bench: SpiBench,
) -> None:
    """Several transfers on one node (a chain's command and its answer's NOPs, chip select
    raised between them) go out as one: between two of them, no other thread can take the
    node (it would put its own transfer there)."""
    spi_bench.chip("tmc2130", cs=0)
    bus = spi_bench.device(0)
    bus.open()
    real = bus.xfer
    free_between: list[bool] = []

    def taken_elsewhere() -> bool:
        got: list[bool] = []

        def try_lock() -> None:
            ok = bus.lock.acquire(blocking=False)
            if ok:
                bus.lock.release()
            got.append(ok)

        t = threading.Thread(target=try_lock)
        t.start()
        t.join(10.0)
        return got == [True]

    def xfer(data: bytes) -> bytes:
        rx = real(data)
        free_between.append(taken_elsewhere())  # after a transfer, before the next
        return rx

    bus.xfer = xfer  # type: ignore[method-assign]
    exchange = [bytes([0x11, i, 0, 0, 0]) for i in range(4)]
    assert len(bus.xfer_many(exchange)) == 4
    assert free_between == [False] * 4
    assert taken_elsewhere()  # and free again after it
    assert bus.transfers == 4
