"""The SPI buses: one per device node, shared by every layer and every chip on it.

A device node ``/dev/spidevB.C`` is one chip select ``C`` of controller ``B``. The HAL opens
each node once (:class:`SpiBus`) and hands the same object to whoever asks for it through
:meth:`SpiBuses.bus`: one chip (a TMC2130), or the N chips of a daisy chain that share the
chip select (ST's dSPIN, docs/dspin.md). Chips on other chip selects of the same controller
have buses of their own, each with its own settings: a TMC5160 at 4 MHz on spidev0.0 beside
a dSPIN chain at 5 MHz on spidev0.1. The machine's :class:`SpiBuses` is its Hardware's
(``Hardware.spi``), so every layer attached to it finds the same buses.

**Settings per node, because the kernel keeps them so.** py-spidev sets ``mode``,
``bits_per_word`` and ``max_speed_hz`` with the SPI_IOC_WR_MODE, _BITS_PER_WORD and
_MAX_SPEED_HZ ioctls on its file descriptor, but spidev stores them in the node's
``spi_device`` (its chip select), for every open of the node alike. So a bus has one
:class:`SpiSettings`, given by its first user; a later user of the node that asks for other
settings is refused (SpiError naming both), never silently given the first one's. Every
chip of a daisy chain sees every transfer anyway, so one clock for the chain is what the
wiring imposes too.

**Locking: one transfer sequence at a time per node.** Every transfer (one ``xfer2``: chip
select held throughout) holds the node's lock, and so does a sequence that must not be
split: :meth:`SpiBus.session` for a caller's own (a TMC pipelined read: n + 1 datagrams),
:meth:`SpiBus.xfer_many` for a daisy-chain exchange (several transfers, chip select raised
between them, each chip's answer in the transfers after its command). Nodes need no lock of
ours between them: the kernel queues each controller's messages one at a time, and a chip
whose chip select stays high ignores the clock.

py-spidev is imported here only, and only when a node is opened without a factory of its
own (:func:`spidev_factory`), so the mock and the tests of everything else never need it.
Tests pass a factory of their own that implements py-spidev's API (``SpiDev()``,
``open(bus, device)``, ``mode``, ``bits_per_word``, ``max_speed_hz``, ``xfer2(list)``,
``close()``; tests/support/tmc_model.py's FakeSpiDev, hal/backends/mock/dspin_chain.py).

Threads: a bus is shared by the threads that talk to its chips (the HAL's driver poller, a
chip's ramp executor on the planner thread, ``--probe``); everything that touches the node
holds its lock. A transfer blocks for the kernel's SPI transfer (tens of microseconds at MHz
clocks) and for the lock: never on the step path. :class:`SpiBuses` hands out buses under a
lock of its own (any thread).
"""

from __future__ import annotations

import errno
import re
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from typing import Protocol

from motorctl.hal.interfaces import HalError

SPI_MODE_3 = 3  # CPOL = 1, CPHA = 1: what the TMC2130/TMC5160 and the dSPIN chips expect
#: every chip family's defaults for its ``spi`` and ``spi_speed_hz`` keys ([motors.tmc],
#: [motors.dspin]): the first device of bus 0, and a clock every supported chip takes
DEFAULT_DEVICE = "/dev/spidev0.0"
DEFAULT_SPEED_HZ = 1_000_000
#: what a ``spi`` key must look like, as the config's pattern and in its error
DEVICE_PATTERN = r"/dev/spidev[0-9]+\.[0-9]+"


class SpiError(HalError):
    """An SPI device could not be opened or a transfer failed; the message names the device."""


class SpiDevLike(Protocol):
    """The part of py-spidev's ``spidev.SpiDev`` that motorctl uses."""

    mode: int
    bits_per_word: int
    max_speed_hz: int

    def open(self, bus: int, device: int) -> None: ...

    def xfer2(self, values: list[int]) -> list[int]: ...

    def close(self) -> None: ...


SpiFactory = Callable[[], SpiDevLike]

_PATH = re.compile(r"^(?:/dev/spidev)?(\d+)\.(\d+)$")


@dataclass(frozen=True, order=True)
class SpiAddress:
    """One SPI device node: controller ``bus`` and chip select ``cs``, i.e.
    ``/dev/spidev<bus>.<cs>``."""

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


@dataclass(frozen=True)
class SpiSettings:
    """How a node's transfers go: SPI mode (0..3: CPOL << 1 | CPHA), clock and word size."""

    speed_hz: int
    mode: int = SPI_MODE_3
    bits_per_word: int = 8

    def describe(self) -> str:
        return f"mode {self.mode}, {self.speed_hz} Hz, {self.bits_per_word}-bit words"


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


class SpiBus:
    """One device node, opened once in its settings, behind its lock.

    Its users open and close it (:meth:`open`, :meth:`close`): the node is opened at the
    first open and closed at the last close, so that chips sharing it do not close it under
    each other. ``transfers`` and ``errors`` count the node's transfers and failed ones.
    """

    def __init__(
        self, address: SpiAddress, settings: SpiSettings, factory: SpiFactory | None = None
    ) -> None:
        self.address = address
        self.settings = settings
        self.lock = threading.RLock()  # re-entrant: a session's transfers take it again
        self.users: list[str] = []
        self.transfers = 0
        self.errors = 0
        self._factory = factory
        self._dev: SpiDevLike | None = None
        self._opens = 0

    @property
    def path(self) -> str:
        return self.address.path

    @property
    def speed_hz(self) -> int:
        return self.settings.speed_hz

    @property
    def mode(self) -> int:
        return self.settings.mode

    @property
    def is_open(self) -> bool:
        return self._dev is not None

    def open(self) -> None:
        """Open the node (the first open) and set its mode, word size and clock; SpiError
        says what is wrong and the fix. Each open wants its close."""
        with self.lock:
            if self._dev is None:
                self._dev = self._open_node()
            self._opens += 1

    def _open_node(self) -> SpiDevLike:
        s = self.settings
        dev = (self._factory or spidev_factory())()
        try:
            dev.open(self.address.bus, self.address.cs)
        except OSError as exc:
            raise SpiError(describe_os_error(self.path, exc, "open")) from exc
        try:
            dev.mode = s.mode
            dev.bits_per_word = s.bits_per_word
            dev.max_speed_hz = s.speed_hz
            if dev.mode != s.mode:
                raise SpiError(f"{self.path} refused SPI mode {s.mode} (it reports {dev.mode})")
        except OSError as exc:
            dev.close()
            raise SpiError(describe_os_error(self.path, exc, "configure")) from exc
        except SpiError:
            dev.close()
            raise
        return dev

    def close(self) -> None:
        """One open's close; the node is closed when the last user closes it (a close
        without an open, or after a failed one, does nothing)."""
        with self.lock:
            self._opens = max(0, self._opens - 1)
            if self._opens:
                return
            dev, self._dev = self._dev, None
            if dev is not None:
                with suppress(OSError):  # closing a device that failed loses nothing
                    dev.close()

    @contextmanager
    def session(self) -> Iterator[SpiBus]:
        """Hold the node for several transfers in a row (a pipelined read)."""
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

    def xfer_many(self, transfers: Sequence[bytes]) -> list[bytes]:
        """Transfers in a row that no other user of the node can come between, chip select
        raised after each (a daisy chain's exchange); what each brought back."""
        with self.lock:
            return [self.xfer(t) for t in transfers]


class SpiBuses:
    """The machine's SPI buses, one per device node, handed out to every layer that asks.

    Made once by the backend that builds the Hardware (``Hardware.spi``), or by whoever
    probes; nothing global.
    """

    def __init__(self) -> None:
        self._buses: dict[SpiAddress, SpiBus] = {}
        self._guard = threading.Lock()

    def bus(
        self,
        address: SpiAddress,
        settings: SpiSettings,
        user: str,
        factory: SpiFactory | None = None,
    ) -> SpiBus:
        """The bus of ``address`` for ``user`` (named in errors and in ``SpiBus.users``),
        made in ``settings`` the first time; a node already set otherwise is a SpiError
        naming both users. ``factory``: py-spidev's API to open the node with (None:
        py-spidev itself, imported when the node is opened); the first user's counts."""
        with self._guard:
            bus = self._buses.get(address)
            if bus is None:
                bus = self._buses[address] = SpiBus(address, settings, factory)
            elif bus.settings != settings:
                raise SpiError(
                    f"{address.path}: {user} needs {settings.describe()}, but "
                    f"{', '.join(bus.users)} on the same chip select needs "
                    f"{bus.settings.describe()}; the kernel keeps one setting per chip "
                    "select: give them the same, or put them on chip selects of their own"
                )
            bus.users.append(user)
            return bus

    def __iter__(self) -> Iterator[SpiBus]:
        with self._guard:
            return iter(list(self._buses.values()))
