"""A device with one answer deliberately changed: a forwarder between a PTY of its own (the
host's side) and a real daemon's PTY that passes every byte unchanged but the answer to one
frame, which it rewrites (with a right checksum). For the replay's tests and benchmark: the
replay must fail naming exactly that frame.

The forwarder runs on a thread of its own (:meth:`Tamper.start`), which owns both file
descriptors until :meth:`Tamper.close`. Answers pair with frames in order (every complete
frame gets exactly one answer), so the n-th 5-byte answer from the daemon answers frame n.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import tty
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from motorctl.protocol.codec import (
    RESPONSE_LEN,
    CodecOptions,
    ErrorCode,
    Response,
    decode_response,
    encode_response,
)

Rewrite = Callable[[Response], Response]
OPTS = CodecOptions()


def other_error(code: ErrorCode) -> Rewrite:
    """The answer replaced by error ``code``."""
    return lambda _resp: Response.error(code)


def position_off(steps: int) -> Rewrite:
    """A position answer moved by ``steps``."""
    return lambda resp: Response.position(resp.as_position + steps)


class Tamper:
    """Forwards between ``self.port`` (open it as the device) and ``device``, rewriting the
    answer to frame ``frame`` (1 = the first) with ``rewrite``."""

    def __init__(self, device: Path, frame: int, rewrite: Rewrite) -> None:
        self.frame = frame
        self.rewrite = rewrite
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave  # held open, so the master never reads EIO between opens
        self.device = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.device)
        self.answers = 0
        self.rewritten: tuple[bytes, bytes] | None = None  # (original, sent)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="tamper", daemon=True)

    def start(self) -> Tamper:
        self._thread.start()
        return self

    def _run(self) -> None:
        poller = select.poll()
        for fd in (self.master, self.device, self._stop_r):
            poller.register(fd, select.POLLIN)
        pending = bytearray()
        while True:
            for fd, _ in poller.poll():
                if fd == self._stop_r:
                    return
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    if exc.errno == errno.EIO:
                        continue
                    raise
                if fd == self.master:
                    _write_all(self.device, data)
                    continue
                pending += data
                while len(pending) >= RESPONSE_LEN:
                    answer = bytes(pending[:RESPONSE_LEN])
                    del pending[:RESPONSE_LEN]
                    _write_all(self.master, self._answer(answer))

    def _answer(self, data: bytes) -> bytes:
        self.answers += 1
        if self.answers != self.frame:
            return data
        changed = encode_response(self.rewrite(decode_response(data, OPTS)), OPTS)
        self.rewritten = (data, changed)
        return changed

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(10)
        for fd in (self.master, self._slave, self.device, self._stop_r, self._stop_w):
            os.close(fd)

    def __enter__(self) -> Tamper:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            view = view[os.write(fd, view) :]
        except BlockingIOError:
            select.select([], [fd], [], 1.0)
