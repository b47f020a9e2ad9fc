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

``--control FILE`` (JSON, read again whenever its mtime changes, before a transfer):
``{"1": ["OCD"]}`` makes those faults present on chip 1 (its chain position), the others
gone. ``--transcript FILE``: one JSON object a line per transfer, written at exit (SIGTERM):
``{"seq", "mode", "speed_hz", "bits", "cs_off", "tx", "rx", "error"}`` (bytes in hex;
``error``: why the chain refused it, e.g. another SPI mode, else null). Prints ``ready`` once
/dev/spi-sim is open.

Owned by this process's one thread. Usage (guest): python3 hwtest/dspin_chain.py --control F
--transcript F [--switch-at N]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import sys
import time
from pathlib import Path
from types import FrameType

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.dont_write_bytecode = True

from motorctl.hal.backends.mock.dspin_chain import DspinChain  # noqa: E402
from motorctl.hal.backends.mock.dspin_chip import DspinChip  # noqa: E402
from motorctl.hal.dspin.chips import L6470, L6480, POWERSTEP01_VOLTAGE  # noqa: E402

DEVICE = "/dev/spi-sim"
#: spi-sim.c's header: seq, len, speed_hz, mode, bits_per_word, cs_off
HEADER = struct.Struct("<IIIHBB")
#: SPI_CPHA | SPI_CPOL: the mode bits py-spidev's ``mode`` sets
MODE_BITS = 0x3
CHIPS = (L6470, L6480, POWERSTEP01_VOLTAGE)


class Responder:
    def __init__(self, control: Path, switch_at: int) -> None:
        self.control = control
        self.seen = 0.0
        self.chips = [DspinChip(c, switch=lambda shaft: shaft <= switch_at) for c in CHIPS]
        self.chain = DspinChain(self.chips)
        self.switch_at = switch_at
        self.last = time.monotonic()
        self.transcript: list[dict[str, object]] = []

    def apply_control(self) -> None:
        try:
            mtime = os.stat(self.control).st_mtime
        except FileNotFoundError:
            return
        if mtime == self.seen:
            return
        self.seen = mtime
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

    def answer(self, head: bytes, tx: bytes) -> bytes:
        seq, length, speed, mode, bits, cs_off = HEADER.unpack(head)
        self.apply_control()
        self.catch_up()
        error = None
        self.chain.mode = mode & MODE_BITS
        try:
            if mode & ~MODE_BITS:
                raise ValueError(f"mode bits {mode:#x}: the chips want plain SPI mode 3")
            rx = bytes(self.chain.xfer2(list(tx)))
        except ValueError as exc:  # the chips would read garbage: they answer nothing
            error, rx = str(exc), bytes(length)
        self.transcript.append(
            {
                "seq": seq,
                "mode": mode,
                "speed_hz": speed,
                "bits": bits,
                "cs_off": cs_off,
                "tx": tx.hex(),
                "rx": rx.hex(),
                "error": error,
            }
        )
        return rx


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--control", type=Path, required=True)
    ap.add_argument("--transcript", type=Path, required=True)
    ap.add_argument("--switch-at", type=int, default=-1000)
    args = ap.parse_args()
    responder = Responder(args.control, args.switch_at)

    def stop(signum: int, frame: FrameType | None) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, stop)
    fd = os.open(DEVICE, os.O_RDWR)
    print("ready", flush=True)
    try:
        while True:
            record = os.read(fd, HEADER.size + 4096)
            head, tx = record[: HEADER.size], record[HEADER.size :]
            os.write(fd, responder.answer(head, tx))
    finally:
        os.close(fd)
        cpu = time.process_time()
        count = len(responder.transcript)
        print(f"dspin_chain: {count} transfers, CPU {cpu:.1f} s", file=sys.stderr)
        lines = "".join(json.dumps(t) + "\n" for t in responder.transcript)
        args.transcript.write_text(lines)


if __name__ == "__main__":
    sys.exit(main())
