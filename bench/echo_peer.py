"""A bare echo peer on a PTY: reads 10-byte frames, answers 5 fixed bytes. The baseline.

``--as-link``: the same answers, but each turn makes the system calls that motorctld's link
makes on its usual turn (daemon/link/loop.py), and nothing else: ``poll()`` on the port, a
wake-up pipe and an inotify watch of the slave's opens and closes (daemon/link/ports.py), the
clock read before the wait and at the read, a non-blocking read, the watch looked at again
after the read (``poll(0)``), the write. No frame is decoded, no command dispatched, nothing
counted: the least CPU a link thread in Python spends a round trip (bench/latency.py's floor).
"""

from __future__ import annotations

import os
import select
import sys
import time
import tty
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

REPLY = bytes([1, 1, 0, 0, 0x6B])  # IsReady: TRUE


def echo(master: int) -> None:
    pending = 0
    while True:
        data = os.read(master, 4096)
        pending += len(data)
        while pending >= 10:
            pending -= 10
            os.write(master, REPLY)


def as_link(master: int, slave_name: str) -> None:
    from motorctl.daemon.link import devwatch
    from motorctl.daemon.link.ports import OPENS

    os.set_blocking(master, False)
    wake_r, _wake_w = os.pipe()
    opens = devwatch.inotify(slave_name, OPENS)
    poller = select.poll()
    poller.register(wake_r, select.POLLIN)
    poller.register(opens, select.POLLIN)
    poller.register(master, select.POLLIN)
    pending_opens = select.poll()
    pending_opens.register(opens, select.POLLIN)
    clock = time.monotonic
    pending = 0
    while True:
        clock()
        poller.poll(None)
        clock()
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            continue
        if pending_opens.poll(0):
            devwatch.read_events(opens)
        pending += len(data)
        while pending >= 10:
            pending -= 10
            os.write(master, REPLY)


def main() -> int:
    link = Path(sys.argv[1])
    master, slave = os.openpty()
    tty.setraw(slave)
    if link.is_symlink():
        link.unlink()
    os.symlink(os.ttyname(slave), link)
    print("ready", flush=True)
    if "--as-link" in sys.argv[2:]:
        as_link(master, os.ttyname(slave))
    else:
        echo(master)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
