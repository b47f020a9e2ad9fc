"""``motorctl tap``: sit between a host and a device, forward every byte, record both ways.

Two serial ports (pyserial: UARTs, USB adapters, PTYs), one thread, one ``poll()`` loop: a
byte run read from one port is written to the other at once, before anything else is done
with it, then recorded (:mod:`motorctl.protocol.capture`'s format, the daemon's trace's:
docs/trace.md). Bytes are never altered, dropped or reordered: what a port does not take at
once waits in that direction's queue, and later runs queue behind it. The recording is
written from a buffer when the loop is idle (and at least every ``FLUSH_S``), so the file
never delays a byte; the tap reports the delay it adds (from ``poll()`` returning with the
bytes to their write returning) when it stops.

Runs on the calling thread until SIGINT or SIGTERM, or until a port closes (a PTY's other
side going away, a USB adapter unplugged); the recording is complete up to that moment.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import select
import signal
import statistics
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any, BinaryIO

import serial

from motorctl import __version__
from motorctl.client.arguments import number_in
from motorctl.client.port_errors import not_a_port
from motorctl.protocol.capture.format import CaptureInfo, Direction
from motorctl.protocol.capture.writer import RecordEncoder, header
from motorctl.protocol.crc import CHECKSUM_DEFAULT
from motorctl.protocol.line import parse_baud

FLUSH_S = 0.2
READ_MAX = 4096
POLLGONE = select.POLLHUP | select.POLLERR | select.POLLNVAL


class TapError(Exception):
    """A port or the output file cannot be used; the message names it and the fix."""


def open_port(path: str, args: argparse.Namespace, what: str) -> Any:
    """The ``what`` ("host", "device") port, open; TapError naming it and the fix. What is
    no character device (a file, a folder, a FIFO) is refused unopened."""
    problem = not_a_port(path)
    if problem is not None:
        raise TapError(f"the {what} port {problem}")
    try:
        return serial.Serial(
            path,
            args.baud,
            bytesize=args.bytesize,
            parity=args.parity,
            stopbits=args.stopbits,
            timeout=0,
            exclusive=True,
        )
    except (serial.SerialException, ValueError, OSError) as exc:
        raise TapError(
            f"cannot open the {what} port {path}: {exc}; check the path, that "
            "nothing else holds it, and that you may use it (group dialout)"
        ) from None


class Tap:
    """Forwards between two open descriptors and records what passes.

    ``host_fd``/``device_fd`` are non-blocking; ``out`` receives the trace (header first)."""

    def __init__(
        self,
        host_fd: int,
        device_fd: int,
        out: BinaryIO,
        info: CaptureInfo,
        clock: Any = time.monotonic,
    ) -> None:
        self.fds = {host_fd: Direction.TO_DEVICE, device_fd: Direction.TO_HOST}
        for fd in self.fds:
            os.set_blocking(fd, False)
        self.peer = {host_fd: device_fd, device_fd: host_fd}
        self.queue: dict[int, bytearray] = {host_fd: bytearray(), device_fd: bytearray()}
        self.out = out
        self.clock = clock
        self._t0 = clock()
        self._wall0 = time.time_ns()
        self._enc = RecordEncoder()
        self._buf = bytearray(header(info))
        self._last_flush = self._t0
        self.delays_ns: list[int] = []
        self.runs = {Direction.TO_DEVICE: 0, Direction.TO_HOST: 0}
        self.bytes = {Direction.TO_DEVICE: 0, Direction.TO_HOST: 0}
        self.queued_max = 0
        self.stopped = False
        self.closed_by: str | None = None

    def stop(self) -> None:
        self.stopped = True

    def serve(self) -> None:
        poller = select.poll()
        masks = dict.fromkeys(self.fds, -1)
        while not self.stopped and self.closed_by is None:
            for fd, q in self.queue.items():  # a port that must take bytes: watch it too
                mask = select.POLLIN | (select.POLLOUT if q else 0)
                if masks[fd] != mask:
                    poller.register(fd, mask)
                    masks[fd] = mask
            try:
                events = poller.poll(FLUSH_S * 1000)
            except InterruptedError:
                continue
            t = self.clock()
            if not events:
                self._flush(t)
                continue
            for fd, ev in events:
                if ev & select.POLLIN:
                    self._forward(fd, t)
                elif ev & POLLGONE:
                    self._gone(fd, "hung up")
                if ev & select.POLLOUT:
                    self._drain(fd)
            if t - self._last_flush >= FLUSH_S:
                self._flush(t)
        self._flush(self.clock())

    def _forward(self, fd: int, t: float) -> None:
        try:
            data = os.read(fd, READ_MAX)
        except BlockingIOError:
            return
        except OSError as exc:
            self._gone(fd, "closed" if exc.errno == errno.EIO else str(exc))
            return
        if not data:
            self._gone(fd, "closed")
            return
        to = self.peer[fd]
        q = self.queue[to]
        if q:
            q += data
        else:
            self._write(to, data)
        done = self.clock()
        direction = self.fds[fd]
        self.delays_ns.append(round((done - t) * 1e9))
        self.runs[direction] += 1
        self.bytes[direction] += len(data)
        ts = self._wall0 + round((t - self._t0) * 1e9)
        self._buf += self._enc.encode(ts, direction, data)

    def _write(self, to: int, data: bytes) -> None:
        try:
            n = os.write(to, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            self._gone(to, "closed" if exc.errno == errno.EIO else str(exc))
            return
        if n < len(data):
            self.queue[to] += data[n:]
            self.queued_max = max(self.queued_max, len(self.queue[to]))

    def _drain(self, to: int) -> None:
        q = self.queue[to]
        if not q:
            return
        try:
            n = os.write(to, q)
        except BlockingIOError:
            return
        except OSError as exc:
            self._gone(to, "closed" if exc.errno == errno.EIO else str(exc))
            return
        del q[:n]

    def _gone(self, fd: int, why: str) -> None:
        side = "host" if self.fds[fd] is Direction.TO_DEVICE else "device"
        self.closed_by = f"the {side} port {why}"

    def _flush(self, t: float) -> None:
        self._last_flush = t
        if self._buf:
            self.out.write(self._buf)
            self.out.flush()
            self._buf.clear()

    def report(self) -> dict[str, Any]:
        d = sorted(self.delays_ns)

        def pct(q: float) -> float:
            return round(d[min(len(d) - 1, int(q / 100 * len(d)))] / 1e3, 1) if d else 0.0

        return {
            "runs_to_device": self.runs[Direction.TO_DEVICE],
            "runs_to_host": self.runs[Direction.TO_HOST],
            "bytes_to_device": self.bytes[Direction.TO_DEVICE],
            "bytes_to_host": self.bytes[Direction.TO_HOST],
            "added_delay_us": {
                "p50": pct(50),
                "p99": pct(99),
                "max": pct(100),
                "mean": round(statistics.mean(d) / 1e3, 1) if d else 0.0,
            },
            "queued_max_bytes": self.queued_max,
            "stopped_by": self.closed_by or "signal",
        }


def baud_rate(text: str) -> int:
    """argparse type: a baud rate (motorctl.protocol.line's rule)."""
    try:
        return parse_baud(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "tap",
        help="forward between a host and a device port, recording both directions",
        description="Open two serial ports, forward every byte both ways unchanged and at "
        "once, and record each byte run with a monotonic timestamp and its direction to "
        "FILE (pcapng, the format of motorctld --trace; read it with 'motorctl trace FILE', "
        "replay it with 'motorctl replay FILE'). Stops on SIGINT/SIGTERM or when a port "
        "closes; then prints what passed and the delay the tap added. docs/trace.md.",
    )
    p.add_argument(
        "--host", required=True, metavar="PORT", help="the port the host is connected to"
    )
    p.add_argument(
        "--device",
        required=True,
        metavar="PORT",
        help="the port the device (the original microcontroller) is on",
    )
    p.add_argument("--out", required=True, type=Path, metavar="FILE", help="the recording")
    p.add_argument(
        "--baud",
        type=baud_rate,
        default=argparse.SUPPRESS,
        help="baud rate of both ports (default 115200)",
    )
    p.add_argument(
        "--parity",
        default="N",
        choices=["N", "E", "O", "M", "S"],
        help="parity of both ports (default N)",
    )
    p.add_argument("--bytesize", type=int, default=8, choices=[5, 6, 7, 8])
    p.add_argument("--stopbits", type=float, default=1, choices=[1, 1.5, 2])
    p.add_argument(
        "--checksum",
        default=argparse.SUPPRESS,
        metavar="NAME",
        help="the link's checksum, written into the recording for the reader "
        f"(default {CHECKSUM_DEFAULT})",
    )
    p.add_argument(
        "--frame-gap-ms",
        type=number_in(0, 10_000, "ms"),
        default=10.0,
        metavar="MS",
        help="the device's frame gap, written into the recording (default 10)",
    )
    p.add_argument("--json", action="store_true", help="print the final report as JSON")


def run(args: argparse.Namespace) -> int:
    info = CaptureInfo(
        role="tap",
        checksum=args.checksum,
        crc_covers_ack=args.crc_covers_ack,
        frame_gap_ms=args.frame_gap_ms,
        port=f"host {args.host} <-> device {args.device}",
        application=f"motorctl tap {__version__}",
        session=os.urandom(6).hex(),  # one file: part 1 of its own session
        part=1,
    )
    try:
        info.codec_options()
    except ValueError as exc:
        print(f"error: --checksum: {exc}", file=sys.stderr)
        return 2
    ports: list[Any] = []
    try:  # the ports first: a port that cannot be used leaves --out as it was (a recording)
        ports.append(open_port(args.host, args, "host"))
        ports.append(open_port(args.device, args, "device"))
        try:
            out = open(args.out, "wb")  # noqa: SIM115 (closed below)
        except OSError as exc:
            raise TapError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    except TapError as exc:
        for port in ports:
            port.close()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    host, device = ports
    tap = Tap(host.fileno(), device.fileno(), out, info)

    def on_signal(signum: int, frame: FrameType | None) -> None:
        tap.stop()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    print(
        f"motorctl tap: forwarding {args.host} (host) <-> {args.device} (device), "
        f"recording to {args.out}; Ctrl-C stops",
        flush=True,
    )
    try:
        tap.serve()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        with contextlib.suppress(OSError):
            out.close()
        host.close()
        device.close()
    rep = tap.report()
    if args.json:
        import json

        print(json.dumps(rep, indent=1))
    else:
        d = rep["added_delay_us"]
        print(
            f"motorctl tap: stopped ({rep['stopped_by']}); host -> device "
            f"{rep['bytes_to_device']} bytes in {rep['runs_to_device']} runs, device -> "
            f"host {rep['bytes_to_host']} bytes in {rep['runs_to_host']} runs; added "
            f"delay (read to written) p50 {d['p50']} us, p99 {d['p99']} us, max {d['max']} "
            f"us; recorded in {args.out}"
        )
    return 0
