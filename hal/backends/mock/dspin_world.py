"""The mock world's dSPIN chains: for every chip select that motors' ``[motors.dspin]``
name, a chain of chip models (dspin_chain.py) that moves the world's axes, behind
py-spidev's API (:class:`MockSpiNodes`, the mock Hardware's ``spi_factory``), so the dSPIN
layer talks to them byte for byte as it talks to a real chain on /dev/spidevB.C.

Time: the chips move by the world's clock, caught up before each transfer (a chip reads
back where its motor is now). Each chip's ``shaft`` moves its axis (``MockAxis.position``:
what the world's status and state file show); its SW input is the axis's end stop on the
side ``[motors.dspin] switch`` names (forced levels included). A node the config names no
chip on does not exist (ENOENT, as the kernel says).

The chips' FLAG and BUSY outputs are the mock's lines where ``[motors.dspin] flag`` and
``busy`` name one (:class:`MockAlertLines`, what ``Hardware.open_alert_lines`` gives on the
mock): low while any chip wired to the line signals (open drain, wired-OR), each change
made known on a pipe as a kernel line request's descriptor makes an edge known.

The chip models are imported when a world's chains are built (:func:`factory_of`, for the
daemon's hardware and ``--probe``): the executor's process, which opens only the world's
step IO (``world.py``), never needs them.

Owned by the daemon's process; transfers come under the SPI bus's lock (hal/spi.py), so
one thread at a time touches a chain; a line's level is read from the chips' state
(a read of Python attributes, from the thread that reads the line).
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

from motorctl.hal.dspin.spec import DspinSpec, chains
from motorctl.hal.interfaces import Clock, Edge, EdgeInputs, HalError
from motorctl.hal.spec import HardwareSpec

if TYPE_CHECKING:
    from motorctl.hal.backends.mock.dspin_chip import DspinChip
    from motorctl.hal.backends.mock.world import MockAxis


class _Moved:
    """One chip and the axis it moves."""

    def __init__(self, axis: MockAxis, spec: DspinSpec) -> None:
        self.axis = axis
        self.spec = spec
        self.side = spec.switch
        self.synced = 0  # the chip's shaft when the axis was last moved to it
        from motorctl.hal.backends.mock.dspin_chip import DspinChip

        self.chip = DspinChip(spec.model, switch=self.switch, stops=self.stops)

    def switch(self, shaft: int) -> bool:
        if self.side == "none":
            return False
        return self.axis.endstop_at(self.side, self.axis.position + shaft - self.synced)

    def stops(self, shaft: int) -> int:
        """The axis's hard stops (its end stops' positions, ``MockAxis``): the shaft as far
        towards ``shaft`` as they let it go."""
        at = self.axis.position + shaft - self.synced
        held = min(max(at, self.axis.endstop_min), self.axis.endstop_max)
        return shaft - (at - held)

    def sync(self) -> None:
        self.axis.position += self.chip.shaft - self.synced
        self.synced = self.chip.shaft


class MockChain:
    """One chip select's chain in the world: the chips, the axes they move, its clock."""

    def __init__(self, members: list[_Moved], clock: Clock) -> None:
        self.members = members
        from motorctl.hal.backends.mock.dspin_chain import DspinChain

        self.chain = DspinChain([m.chip for m in members])
        self.clock = clock
        self.last = clock.now()

    def catch_up(self) -> None:
        now = self.clock.now()
        if now > self.last:
            self.chain.advance(now - self.last)
            self.last = now
        for m in self.members:
            m.sync()
            if not m.chip.motion.idle:
                continue
            m.chip.set_switch(m.switch(m.chip.shaft))  # a forced or moved end stop


class _Node:
    """py-spidev's ``SpiDev`` over the world's chains."""

    def __init__(self, chains: dict[tuple[int, int], MockChain]) -> None:
        self._chains = chains
        self._chain: MockChain | None = None
        self.mode = 0
        self.bits_per_word = 8
        self.max_speed_hz = 500_000

    def open(self, bus: int, device: int) -> None:
        chain = self._chains.get((bus, device))
        if chain is None:
            path = f"/dev/spidev{bus}.{device}"
            raise OSError(errno.ENOENT, os.strerror(errno.ENOENT), path)
        self._chain = chain

    def xfer2(self, values: list[int]) -> list[int]:
        chain = self._chain
        if chain is None:
            raise OSError(errno.EBADF, "the mock SPI node is not open")
        chain.catch_up()
        chain.chain.mode = self.mode
        try:
            return chain.chain.xfer2(values)
        except ValueError as exc:  # another SPI mode: the chips would read garbage
            raise OSError(errno.EIO, str(exc)) from exc

    def close(self) -> None:
        self._chain = None


class MockAlertLines(EdgeInputs):
    """Lines driven by chips' open-drain outputs: line ``i`` is active (low) while one of
    ``wired[i]`` (a chip and its output, ``flag`` or ``busy``) signals. The chips call
    :meth:`_changed` when their outputs may have changed; a change of a line writes a byte
    to the pipe whose read end is :meth:`fileno`; :meth:`read_edges` drains it and gives
    each changed line's edge, timed when it is read (the world's clock)."""

    def __init__(
        self, names: Sequence[str], wired: list[list[tuple[DspinChip, str]]], clock: Clock
    ) -> None:
        super().__init__(names)
        self.wired = wired
        self.clock = clock
        self._r, self._w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self.levels = [self._sense(i) for i in range(len(wired))]
        self._told = list(self.levels)
        self.chips = {id(c): c for line in wired for c, _ in line}
        for chip in self.chips.values():
            chip.listeners.append(self._changed)

    def _sense(self, line: int) -> bool:
        return any(getattr(chip, output) for chip, output in self.wired[line])

    def _changed(self) -> None:
        now = [self._sense(i) for i in range(len(self.wired))]
        if now != self._told:
            self._told = now
            with contextlib.suppress(BlockingIOError):  # a full pipe wakes its reader too
                os.write(self._w, b"!")

    def read_edges(self) -> list[Edge]:
        with contextlib.suppress(BlockingIOError):
            while os.read(self._r, 4096):
                pass
        out: list[Edge] = []
        t = self.clock.now()
        for i, level in enumerate(self.levels):
            now = self._sense(i)
            if now != level:
                self.levels[i] = now
                out.append(Edge(i, now, t))
        return out

    def level(self, line: int) -> bool:
        return self.levels[line]

    def fileno(self) -> int | None:
        return self._r

    def close(self) -> None:
        for chip in self.chips.values():
            if self._changed in chip.listeners:
                chip.listeners.remove(self._changed)
        if self._r >= 0:
            os.close(self._r)
            os.close(self._w)
            self._r = self._w = -1


class MockSpiNodes:
    """The world's SPI nodes: call it for a new ``SpiDev`` (a py-spidev factory)."""

    def __init__(self, spec: HardwareSpec, axes: list[MockAxis], clock: Clock) -> None:
        self.chains: dict[tuple[int, int], MockChain] = {}
        for node, members in chains(spec).items():
            bus, _, cs = node.removeprefix("/dev/spidev").partition(".")
            moved = [_Moved(axes[i], s) for i, s in members]
            self.chains[(int(bus), int(cs))] = MockChain(moved, clock)

    def __call__(self) -> _Node:
        return _Node(self.chains)

    def alert_lines(self, uses: Sequence[tuple[str, str]], clock: Clock) -> MockAlertLines:
        """The lines ``uses`` names (``[motors.dspin] flag``/``busy`` texts) as the chips
        wired to them drive them."""
        wired: list[list[tuple[DspinChip, str]]] = []
        for use, line in uses:
            found = [
                (m.chip, output)
                for chain in self.chains.values()
                for m in chain.members
                for output in ("flag", "busy")
                if getattr(m.spec, output) == line
            ]
            if not found:
                raise HalError(f"{use}: no simulated dSPIN chip drives the line {line!r}")
            wired.append(found)
        return MockAlertLines([use for use, _ in uses], wired, clock)

    def chip(self, axis: int, spec: HardwareSpec) -> DspinChip:
        """The chip model that moves axis ``axis`` (tests inject faults into it)."""
        driver = spec.axes[axis].driver
        if not isinstance(driver, DspinSpec):
            raise ValueError(f"motor {axis} has no dSPIN chip")
        bus, _, cs = driver.spi.removeprefix("/dev/spidev").partition(".")
        return self.chains[(int(bus), int(cs))].members[driver.position].chip


def factory_of(spec: HardwareSpec, axes: list[MockAxis], clock: Clock) -> MockSpiNodes | None:
    """The world's SPI nodes, when the spec has dSPIN chips (None: no simulated SPI)."""
    return MockSpiNodes(spec, axes, clock) if chains(spec) else None
