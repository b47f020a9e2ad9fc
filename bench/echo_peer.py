"""A bare echo peer on a PTY: reads 10-byte frames, answers 5 fixed bytes. The baseline."""

from __future__ import annotations

import os
import sys
import tty
from pathlib import Path


def main() -> int:
    link = Path(sys.argv[1])
    master, slave = os.openpty()
    tty.setraw(slave)
    if link.is_symlink():
        link.unlink()
    os.symlink(os.ttyname(slave), link)
    print("ready", flush=True)
    reply = bytes([1, 1, 0, 0, 0x6B])  # IsReady: TRUE
    pending = 0
    while True:
        data = os.read(master, 4096)
        pending += len(data)
        while pending >= 10:
            pending -= 10
            os.write(master, reply)


if __name__ == "__main__":
    raise SystemExit(main())
