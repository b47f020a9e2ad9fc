"""SPI devices through py-spidev, and the locks that share one bus between drivers.

py-spidev is imported here only, and only when :func:`spidev_factory` is called, so the mock
and the tests of everything else never need it. Tests pass a factory of their own that
implements py-spidev's API (``SpiDev()``, ``open(bus, device)``, ``mode``, ``max_speed_hz``,
``xfer2(list)``, ``close()``).

Threads: a :class:`SpiDevice` is shared by the threads that talk to its chip (the driver
monitor, a TMC5160 ramp executor, ``--probe``). Every transfer happens with the device's bus
lock held; callers that need several datagrams in a row (a pipelined read) take the lock
themselves with :meth:`SpiDevice.session`. A transfer blocks for the kernel's SPI transfer
(tens of microseconds at MHz clocks) and for the bus lock; never call it on the step path.
"""

from __future__ import annotations

import errno
import re
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from typing import Protocol

from motorctl.hal.interfaces import HalError

SPI_MODE_3 = 3  # CPOL = 1, CPHA = 1: what the TMC2130/TMC5160 expect


class SpiError(HalError):
    """An SPI device could not be opened or a transfer failed; the message names the device."""


class SpiDevLike(Protocol):
    """The part of py-spidev's ``spidev.SpiDev`` that motorctl uses."""

    mode: int
    max_speed_hz: int

    def open(self, bus: int, device: int) -> None: ...

    def xfer2(self, values: list[int]) -> list[int]: ...

    def close(self) -> None: ...


SpiFactory = Callable[[], SpiDevLike]

_PATH = re.compile(r"^(?:/dev/spidev)?(\d+)\.(\d+)$")


@dataclass(frozen=True, order=True)
class SpiAddress:
    """One SPI device: ``bus`` and chip select ``cs``, i.e. ``/dev/spidev<bus>.<cs>``."""

    bus: int
    cs: int

    @property
    def path(self) -> str:
        return f"/dev/spidev{self.bus}.{self.cs}"

    @classmethod
    def parse(cls, text: str) -> SpiAddress:
        """``/dev/spidevB.C`` or ``B.C``; anything else: ValueError saying what is accepted."""
        m = _PATH.match(text.strip())
        if m is None:
            raise ValueError(
                f"{text!r} is not an SPI device: write /dev/spidevB.C (bus B, chip select C), "
                "for example /dev/spidev0.0"
            )
        return cls(int(m.group(1)), int(m.group(2)))

    def __str__(self) -> str:
        return self.path


def spidev_factory() -> SpiFactory:
    """py-spidev's ``SpiDev`` class; a HalError saying how to install it when it is missing."""
    try:
        import spidev
    except ImportError as exc:
        raise HalError(
            f"the Python module 'spidev' is missing ({exc}): install it with "
            "'sudo apt-get install python3-spidev' (Debian, Raspberry Pi OS) or "
            "'pip install spidev' (in the daemon's virtualenv)"
        ) from exc
    factory: SpiFactory = spidev.SpiDev
    return factory


def describe_os_error(path: str, exc: OSError, action: str) -> str:
    """A sentence naming the device, what failed and the fix a user can apply."""
    code = exc.errno
    reason = exc.strerror or str(exc)
    if code == errno.ENOENT:
        return (
            f"{path} does not exist: SPI is not enabled or the bus/chip select is wrong "
            "(Raspberry Pi: add 'dtparam=spi=on' to /boot/firmware/config.txt and reboot; "
            "'ls /dev/spidev*' lists the devices there are)"
        )
    if code in (errno.EACCES, errno.EPERM):
        return (
            f"no permission to {action} {path}: add the daemon's user to the group that owns "
            "it ('sudo usermod -aG spi USER', then log in again) or run the service as a "
            "member of that group"
        )
    if code == errno.EBUSY:
        return f"{path} is busy: another program holds it ({reason}); stop that program"
    return f"cannot {action} {path}: {reason} (errno {code})"


class SpiBuses:
    """One lock per SPI bus number, shared by every chip select on that bus.

    Made once by the backend that opens the devices and passed to each of them; nothing
    global. The lock is re-entrant so that a session can call :meth:`SpiDevice.xfer`.
    """

    def __init__(self) -> None:
        self._locks: dict[int, threading.RLock] = {}
        self._guard = threading.Lock()

    def lock(self, bus: int) -> threading.RLock:
        with self._guard:
            lock = self._locks.get(bus)
            if lock is None:
                lock = self._locks[bus] = threading.RLock()
            return lock


class SpiDevice:
    """One opened ``/dev/spidevB.C`` in a fixed mode and clock, behind its bus lock."""

    def __init__(
        self,
        address: SpiAddress,
        buses: SpiBuses,
        factory: SpiFactory,
        speed_hz: int,
        mode: int = SPI_MODE_3,
    ) -> None:
        self.address = address
        self.lock = buses.lock(address.bus)
        self.speed_hz = speed_hz
        self.mode = mode
        self.transfers = 0
        self.errors = 0
        self._factory = factory
        self._dev: SpiDevLike | None = None

    @property
    def path(self) -> str:
        return self.address.path

    def open(self) -> None:
        """Open the device and set mode and clock; SpiError says what is wrong and the fix."""
        with self.lock:
            if self._dev is not None:
                return
            dev = self._factory()
            try:
                dev.open(self.address.bus, self.address.cs)
            except OSError as exc:
                raise SpiError(describe_os_error(self.path, exc, "open")) from exc
            try:
                dev.mode = self.mode
                dev.max_speed_hz = self.speed_hz
                if dev.mode != self.mode:
                    raise SpiError(
                        f"{self.path} refused SPI mode {self.mode} (it reports {dev.mode})"
                    )
            except OSError as exc:
                dev.close()
                raise SpiError(describe_os_error(self.path, exc, "configure")) from exc
            self._dev = dev

    def close(self) -> None:
        with self.lock:
            dev, self._dev = self._dev, None
            if dev is not None:
                with suppress(OSError):  # closing a device that failed loses nothing
                    dev.close()

    @contextmanager
    def session(self) -> Iterator[SpiDevice]:
        """Hold the bus for several transfers in a row (pipelined reads)."""
        with self.lock:
            yield self

    def xfer(self, data: bytes) -> bytes:
        """One full-duplex transfer with chip select held throughout; SpiError on failure."""
        with self.lock:
            dev = self._dev
            if dev is None:
                raise SpiError(f"{self.path} is not open")
            try:
                rx = dev.xfer2(list(data))  # xfer2 overwrites the list it is given
            except OSError as exc:
                self.errors += 1
                raise SpiError(describe_os_error(self.path, exc, "transfer on")) from exc
            self.transfers += 1
            if len(rx) != len(data):
                self.errors += 1
                raise SpiError(f"{self.path}: {len(data)} bytes sent but {len(rx)} received")
            return bytes(rx)
