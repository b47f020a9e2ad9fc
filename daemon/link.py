"""The link: bytes in, frames out, exactly one response per complete frame, in order.

One thread does all of it (as pyserial's ReaderThread does the reading): it waits
in select() on the serial/PTY file descriptor and a wake-up pipe, stamps every
read with the monotonic clock (pyserial's inter_byte_timeout has 0.1 s resolution,
useless for a 10 ms gap), frames, decodes, dispatches and writes. While a
WaitMoved is pending, later frames are kept in arrival order (up to
``held_frames``; beyond that each gets E0 in its turn); a StopMove among them is
executed on arrival and its response waits its turn.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from motorctl.daemon.dispatcher import Dispatcher, Wait
from motorctl.motion.latency import LatencyStats
from motorctl.protocol.codec import (
    CodecOptions,
    Command,
    ErrorCode,
    FrameError,
    Response,
    StopMove,
    WaitMoved,
    decode_command,
    encode_response,
)
from motorctl.protocol.framing import Framer

log = logging.getLogger("motorctl.link")


@dataclass
class Held:
    """A frame kept behind a pending WaitMoved: a command, or an answer already decided."""

    command: Command | None
    response: Response | None
    counts: bool = True  # E0 overflow answers do not occupy the buffer


class Link:
    def __init__(
        self,
        fd: int,
        dispatcher: Dispatcher,
        options: CodecOptions,
        frame_gap_s: float,
        held_frames: int = 16,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.fd = fd
        self.dispatcher = dispatcher
        self.options = options
        self.framer = Framer(frame_gap_s)
        self.held_limit = held_frames
        self.clock = clock
        self.counters: Counter[str] = Counter()
        self.processing = LatencyStats(threshold_s=108e-6)
        self.wait: Wait | None = None
        self.held: list[Held] = []
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._running = False

    # -- thread-safe pokes ---------------------------------------------------------
    def wake(self) -> None:
        """Make the loop re-check a held WaitMoved (called on motor idle/fault)."""
        if self.wait is not None:
            with contextlib.suppress(BlockingIOError):
                os.write(self._wake_w, b"\0")

    def stop(self) -> None:
        self._running = False
        with contextlib.suppress(BlockingIOError):
            os.write(self._wake_w, b"\1")

    # -- the loop --------------------------------------------------------------------
    def serve(self) -> None:
        self._running = True
        fd, wake_r = self.fd, self._wake_r
        while self._running:
            timeout = self._timeout()
            ready, _, _ = select.select([fd, wake_r], [], [], timeout)
            now = self.clock()
            if wake_r in ready:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
            if fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError as exc:
                    if exc.errno in (errno.EAGAIN, errno.EINTR):
                        continue
                    if exc.errno == errno.EIO:  # PTY with no reader: wait for one
                        self._sleep_on_wake(0.05)
                        continue
                    raise
                if data:
                    self.counters["bytes_in"] += len(data)
                    for frame in self.framer.feed(data, now):
                        self._on_frame(frame, now)
            self.framer.expire(now)
            if self.wait is not None:
                self._poll_wait(now)

    def _sleep_on_wake(self, seconds: float) -> None:
        select.select([self._wake_r], [], [], seconds)

    def _timeout(self) -> float | None:
        now = self.clock()
        deadlines = [d for d in (self.framer.deadline(),) if d is not None]
        if self.wait is not None:
            deadlines.append(self.wait.deadline)
        if not deadlines:
            return None
        return max(0.0, min(deadlines) - now)

    # -- frames ------------------------------------------------------------------------
    def _on_frame(self, frame: bytes, t_read: float) -> None:
        try:
            cmd: Command | None = decode_command(frame, self.options)
            self.counters["frames_good"] += 1
        except FrameError as exc:
            self.counters[f"{exc.reason}_errors"] += 1
            cmd = None
        if self.wait is not None:
            self._hold(cmd)
            return
        if cmd is None:
            self._send(Response.error(ErrorCode.INVALID_COMMAND), t_read)
        elif isinstance(cmd, WaitMoved):
            self._begin_wait(cmd, t_read)
        else:
            self._send(self.dispatcher.handle(cmd), t_read)

    def _hold(self, cmd: Command | None) -> None:
        if cmd is None:
            self.held.append(Held(None, Response.error(ErrorCode.INVALID_COMMAND)))
        elif sum(h.counts for h in self.held) >= self.held_limit:
            self.held.append(Held(None, Response.error(ErrorCode.FULL_BUFFER), counts=False))
        elif isinstance(cmd, StopMove):
            self.held.append(Held(None, self.dispatcher.handle(cmd)))
            self._poll_wait(self.clock())
        else:
            self.held.append(Held(cmd, None))

    def _begin_wait(self, cmd: WaitMoved, t_read: float | None) -> None:
        result = self.dispatcher.wait_begin(cmd, self.clock())
        if isinstance(result, Wait):
            self.wait = result
            # The motor may have stopped between the check and now, when wake() still
            # saw no wait to report: look once more.
            self._poll_wait(self.clock())
        else:
            self._send(result, t_read)

    def _poll_wait(self, now: float) -> None:
        wait = self.wait
        assert wait is not None
        result = self.dispatcher.wait_poll(wait, now)
        if result is None:
            return
        self.wait = None
        self._send(result, None)
        while self.held and self.wait is None:
            item = self.held.pop(0)
            if item.response is not None:
                self._send(item.response, None)
            elif isinstance(item.command, WaitMoved):
                self._begin_wait(item.command, None)
            elif item.command is not None:
                self._send(self.dispatcher.handle(item.command), None)

    def _send(self, resp: Response, t_read: float | None) -> None:
        data = encode_response(resp, self.options)
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            view = view[n:]
        if t_read is not None:
            self.processing.record(self.clock() - t_read)
        code = resp.error_code
        self.counters["responses"] += 1
        if code is not None:
            self.counters[f"sent_{code.short}"] += 1

    def status(self) -> dict[str, object]:
        counts: dict[str, object] = dict(self.counters)
        counts["gap_discards"] = self.framer.discarded
        return {"counters": counts, "processing": self.processing.summary(),
                "held": len(self.held), "waiting": self.wait is not None}

    def close(self) -> None:
        os.close(self._wake_r)
        os.close(self._wake_w)
