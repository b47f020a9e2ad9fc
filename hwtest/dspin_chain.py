"""A dSPIN chain of three behind a real kernel SPI bus, in the gpio-sim guest.

spi-sim.c loaded with user=1 (the guest's GSIM_SPI=user) makes /dev/spidev0.0 on a bus whose
transfers this program answers through /dev/spi-sim: for each transfer the kernel's SPI core
hands over (the daemon's own py-spidev calls through spidev's ioctls, in the mode the daemon
set) it reads a header and the bytes out, and writes the bytes back. Behind it: the mock
backend's register-level chip models (hal/backends/mock/dspin_chip.py) as one daisy chain
(dspin_chain.py), an L6470, an L6480 and a powerSTEP01 in voltage mode as
docs/examples/dspin.toml has them, chip 0 at MOSI; they move on this process's monotonic
clock. Each chip's SW input closes while its shaft is at or below ``--switch-at``
microsteps (from where it powered up): the end stop below each axis.

The chips' open-drain FLAG and BUSY outputs (``--flag``, ``--busy``: a gpio-sim line per
chip, ``chip:offset``, in chain order; ``-``: not wired; one line named for several chips is
wired-OR) are driven through gpio-sim's sysfs ``pull`` of the line (hwtest/gsim.py):
``pull-down`` while a chip on the line signals (FLAG: an alarm ALARM_EN enables; BUSY: a
command runs), else ``pull-up``, as the chip models' ``flag``/``busy`` say after each
transfer and each change of the control file. A daemon holding the line as an input sees
the edges, as from a real chip; its request's pull-up bias sets the same ``pull``, which
agrees while no chip on the line signals (the daemon requests the lines after its start-up
GetStatus cleared the power-up flags).

``--control FILE`` (JSON, read again whenever its mtime changes: before a transfer, and
every ``WATCH_S`` between transfers, so an injected fault drives FLAG at once, not at the
daemon's next transfer): ``{"1": ["OCD"]}`` makes those faults present on chip 1 (its chain
position), the others gone. ``--transcript FILE``: one JSON object a line per transfer,
written at exit (SIGTERM): ``{"seq", "t", "mode", "speed_hz", "bits", "cs_off", "tx", "rx",
"error", "flag", "busy"}`` (bytes in hex; ``t``: CLOCK_MONOTONIC when it was answered;
``error``: why the chain refused it, e.g. another SPI mode, else null; ``flag``/``busy``:
each chip's output after it, 1 = signalling, the pin low). Prints ``ready`` once
/dev/spi-sim is open.

Threads: the main thread answers transfers; a watcher thread (``dspin-chain-control``)
applies the control file between them; the chain, the lines and the transcript are touched
only under the :class:`Responder`'s lock. Usage (guest): python3 hwtest/dspin_chain.py
--control F --transcript F [--switch-at N] [--flag L,L,L] [--busy L,L,L]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import FrameType

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.dont_write_bytecode = True

from hwtest import gsim  # noqa: E402
from motorctl.hal.backends.mock.dspin_chain import DspinChain  # noqa: E402
from motorctl.hal.backends.mock.dspin_chip import DspinChip  # noqa: E402
from motorctl.hal.dspin.chips import L6470, L6480, POWERSTEP01_VOLTAGE  # noqa: E402

DEVICE = "/dev/spi-sim"
#: spi-sim.c's header: seq, len, speed_hz, mode, bits_per_word, cs_off
HEADER = struct.Struct("<IIIHBB")
#: SPI_CPHA | SPI_CPOL: the mode bits py-spidev's ``mode`` sets
MODE_BITS = 0x3
CHIPS = (L6470, L6480, POWERSTEP01_VOLTAGE)
#: the chips' open-drain outputs this program can drive onto gpio-sim lines
OUTPUTS = ("flag", "busy")
#: how often the watcher thread looks at the control file between transfers
WATCH_S = 0.02

#: a gpio-sim line: its chip and offset
Line = tuple[str, int]
#: drives a line: (chip, offset, high)
Drive = Callable[[str, int, bool], None]


def sysfs_drive(chip: str, offset: int, high: bool) -> None:
    """What the outside world drives onto the line: gpio-sim's ``pull``."""
    gsim.sim_pull(offset, high, chip)


def parse_lines(text: str) -> list[Line | None]:
    """``--flag``/``--busy``: a line per chip in chain order, ``chip:offset`` or ``-``."""
    parts = text.split(",")
    if len(parts) != len(CHIPS):
        raise argparse.ArgumentTypeError(f"{text!r}: one line per chip of {len(CHIPS)}")
    out: list[Line | None] = []
    for part in parts:
        chip, sep, offset = part.partition(":")
        if part == "-":
            out.append(None)
        elif sep and chip and offset.isdigit():
            out.append((chip, int(offset)))
        else:
            raise argparse.ArgumentTypeError(f"{part!r}: a line is chip:offset (gpiochip0:17) or -")
    return out


class Responder:
    """The chain, its lines and its transcript; see the module's doc for the threads."""

    def __init__(
        self,
        control: Path,
        switch_at: int,
        wiring: Mapping[str, Sequence[Line | None]] | None = None,
        drive: Drive = sysfs_drive,
    ) -> None:
        self.control = control
        self.seen = 0
        self.chips = [DspinChip(c, switch=lambda shaft: shaft <= switch_at) for c in CHIPS]
        self.chain = DspinChain(self.chips)
        self.switch_at = switch_at
        self.last = time.monotonic()
        self.transcript: list[dict[str, object]] = []
        self.lock = threading.Lock()
        #: each wired line and the chips' outputs on it (wired-OR)
        self.lines: dict[Line, list[tuple[DspinChip, str]]] = {}
        for output, lines in (wiring or {}).items():
            if output not in OUTPUTS:
                raise ValueError(f"{output}: the chips' outputs are {', '.join(OUTPUTS)}")
            for chip, line in zip(self.chips, lines, strict=True):
                if line is not None:
                    self.lines.setdefault(line, []).append((chip, output))
        self.drive_line = drive
        self.driven: dict[Line, bool] = {}
        self.drive()

    def drive(self) -> None:
        """Each wired line to the level its chips give it now: low while one signals."""
        for line, outputs in self.lines.items():
            high = not any(getattr(chip, output) for chip, output in outputs)
            if self.driven.get(line) is not high:
                self.drive_line(*line, high)
                self.driven[line] = high

    def control_changed(self) -> bool:
        try:
            return os.stat(self.control).st_mtime_ns != self.seen
        except FileNotFoundError:
            return False

    def apply_control(self) -> None:
        self.seen = os.stat(self.control).st_mtime_ns
        wanted = json.loads(self.control.read_text())
        for i, chip in enumerate(self.chips):
            faults = set(wanted.get(str(i), []))
            for fault in chip.active - faults:
                chip.inject(fault, present=False)
            for fault in faults - chip.active:
                chip.inject(fault)

    def catch_up(self) -> None:
        now = time.monotonic()
        for chip in self.chips:
            if chip.motion.idle:  # (advance() would only work out its ramps, at a cost)
                chip.set_switch(chip.shaft <= self.switch_at)
            else:
                chip.advance(now - self.last)
        self.last = now

    def tick(self) -> None:
        """The control file applied if it changed (the chips caught up to now first) and
        the lines driven; the caller holds the lock."""
        if self.control_changed():
            self.catch_up()
            self.apply_control()
        self.drive()

    def watch(self, stop: threading.Event) -> None:
        """The watcher thread: the control file between transfers."""
        while not stop.wait(WATCH_S):
            with self.lock:
                self.tick()

    def answer(self, head: bytes, tx: bytes) -> bytes:
        seq, length, speed, mode, bits, cs_off = HEADER.unpack(head)
        with self.lock:
            self.tick()
            self.catch_up()
            error = None
            self.chain.mode = mode & MODE_BITS
            try:
                if mode & ~MODE_BITS:
                    raise ValueError(f"mode bits {mode:#x}: the chips want plain SPI mode 3")
                rx = bytes(self.chain.xfer2(list(tx)))
            except ValueError as exc:  # the chips would read garbage: they answer nothing
                error, rx = str(exc), bytes(length)
            self.drive()  # before the answer: the daemon reads the lines after it
            self.transcript.append(
                {
                    "seq": seq,
                    "t": time.monotonic(),
                    "mode": mode,
                    "speed_hz": speed,
                    "bits": bits,
                    "cs_off": cs_off,
                    "tx": tx.hex(),
                    "rx": rx.hex(),
                    "error": error,
                    **{out: [int(getattr(c, out)) for c in self.chips] for out in OUTPUTS},
                }
            )
        return rx


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--control", type=Path, required=True)
    ap.add_argument("--transcript", type=Path, required=True)
    ap.add_argument("--switch-at", type=int, default=-1000)
    for output in OUTPUTS:
        ap.add_argument(f"--{output}", type=parse_lines, help="chip:offset,... or -, per chip")
    args = ap.parse_args()
    wiring = {o: getattr(args, o) for o in OUTPUTS if getattr(args, o) is not None}
    responder = Responder(args.control, args.switch_at, wiring)

    def stop(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    fd = os.open(DEVICE, os.O_RDWR)
    done = threading.Event()
    watcher = threading.Thread(
        target=responder.watch, args=(done,), name="dspin-chain-control", daemon=True
    )
    watcher.start()
    print("ready", flush=True)
    try:
        while True:
            record = os.read(fd, HEADER.size + 4096)
            head, tx = record[: HEADER.size], record[HEADER.size :]
            os.write(fd, responder.answer(head, tx))
    finally:
        done.set()
        watcher.join(5.0)
        os.close(fd)
        cpu = time.process_time()
        count = len(responder.transcript)
        print(f"dspin_chain: {count} transfers, CPU {cpu:.1f} s", file=sys.stderr)
        lines = "".join(json.dumps(t) + "\n" for t in responder.transcript)
        args.transcript.write_text(lines)


if __name__ == "__main__":
    sys.exit(main())
