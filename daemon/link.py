"""The link: the poll/read/write loop around a pure :class:`~motorctl.daemon.session.LinkSession`.

One thread (the link thread) owns this object and its session; it blocks only in ``poll()``
on the serial/PTY file descriptor and a wake-up pipe, in the dispatcher's engine lock, and
after a hard StopMove in the wait for the executor's confirmation (bounded by
``step_thread.stop_confirm_ms``, and not repeated while an earlier one timed out, so a burst
of frames cannot keep a turn from ending and :meth:`stop` is noticed promptly).
:meth:`Link.wake` and :meth:`Link.stop` are the only calls other threads (the step thread,
signal handlers) make: they write a byte to the pipe. The same pipe is the process's signal
wake-up descriptor (:attr:`Link.signal_fd`, ``signal.set_wakeup_fd``): a signal whose Python
handler has not run yet when the loop goes to sleep still wakes it (see :meth:`serve`).
:meth:`Link.status` may be called from the status thread: it only copies counters whose keys
all exist from the start, and the session's last frames (decoded there, on that thread).

What the shell does, and why:
- **Gaps are watched, not inferred.** Before each ``poll()`` it notes the time; when the poll
  returns without input (a timeout or a wake-up), it reads the clock and then confirms with a
  non-blocking read that nothing came. Only then does it tell the session that the line was
  silent for that stretch, while ready to read. Bytes that waited in the kernel's buffer while
  the daemon was busy or not scheduled are read as contiguous, however late. (What this can
  and cannot detect: docs/protocol.md, "Framing".)
- **Writes never block.** Responses go into an output buffer written as the descriptor takes
  them. While more than ``out_limit`` bytes or ``backlog_limit`` responses are owed, the
  shell stops reading: the host's writes then wait in the kernel (back pressure), nothing is
  lost and memory stays bounded. Reads resume as soon as the host reads again.
- **The peer may go away.** A PTY whose other side is closed reports POLLHUP and EIO. The
  partial frame and unsent responses are dropped (like bytes sent down a UART to a closed
  port; ``on_hangup`` also flushes what the kernel still holds for the closed PTY, see
  :func:`flush_pty_input`), and the shell looks every ``retry_s`` whether the port is open
  again, executing held frames meanwhile. Any other read or write error is logged, counted
  and treated the same way: the thread never dies.
- **A serial device may go away** (``device``: ``--port``; a USB adapter unplugged, a
  socat PTY torn down). Its descriptor is hung up for good (POLLHUP, an empty read, EIO),
  so the shell closes it, logs the loss once and opens the device's *path* again on a
  :class:`~motorctl.daemon.serialport.Backoff` schedule (50 ms after the loss, doubling up
  to every second) until it is back; everything else (motors, positions, held frames) is
  kept, and what the partial frame and unsent answers were is dropped as above.
- **The host's silence** (``watch``: ``[link] timeout_ms``, off by default): every byte
  read tells the :class:`~motorctl.daemon.silence.SilenceWatch`; its deadline bounds the
  waits, and when it passes the watch stops the motors in motion.
- **Shutdown is bounded.** :meth:`stop` ends the loop at its next turn; unsent responses get
  at most ``drain_s`` to leave.
- **A recorder may listen.** Given one (``motorctld --trace``), every byte run read from the
  host and every run written to it is handed to it with this loop's own clock reading, on
  this thread (:class:`ByteRecorder`; the daemon's is :mod:`motorctl.daemon.trace`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import termios
import time
from collections import Counter
from collections.abc import Callable
from typing import Protocol

from motorctl.daemon.serialport import Backoff, DeviceError
from motorctl.daemon.session import CommandPort, LinkSession
from motorctl.daemon.silence import SilenceWatch
from motorctl.motion.latency import LatencyStats
from motorctl.protocol.codec import RESPONSE_LEN, CodecOptions

log = logging.getLogger("motorctl.link")

POLLIN, POLLOUT = select.POLLIN, select.POLLOUT
POLLGONE = select.POLLHUP | select.POLLERR | select.POLLNVAL

WRITE_MAX = 65536  # bytes handed to one write()

SHELL_COUNTERS = (
    "reads",
    "read_eagain",
    "write_eagain",
    "link_errors",
    "peer_closed",
    "peer_reopened",
    "hangup_partial_bytes",
    "responses_dropped",
    "backpressure",
    "device_lost",
    "device_reopened",
    "reopen_attempts",
)
#: errors of a reopen that only say the device is not back yet (logged at debug level);
#: any other (no permission, busy) is logged once as a warning: the user must act
NOT_BACK = frozenset({errno.ENOENT, errno.ENXIO, errno.ENODEV, errno.EIO})


class Device(Protocol):
    """A serial device that can be opened again by its path (daemon.serialport)."""

    path: str

    def open(self) -> int: ...  # a fresh non-blocking descriptor, or DeviceError

    def close(self) -> None: ...


class ByteRecorder(Protocol):
    """Told each byte run the link reads or writes, with the link clock's reading (called on
    the link thread: it must not block)."""

    def received(self, data: bytes, t: float) -> None: ...

    def sent(self, data: bytes, t: float) -> None: ...


def flush_pty_input(slave: str) -> None:
    """Discard what was written to a PTY and not read before its host closed it.

    The kernel keeps such bytes for whoever opens the slave next, which would then read
    answers to someone else's questions. Opening the slave for a moment and flushing its
    input is the only way from the master's side; failures are logged, never raised."""
    try:
        fd = os.open(slave, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError as exc:
        log.warning("cannot open %s to flush stale responses: %s", slave, exc)
        return
    try:
        termios.tcflush(fd, termios.TCIFLUSH)
    except termios.error as exc:
        log.warning("cannot flush stale responses on %s: %s", slave, exc)
    finally:
        os.close(fd)


class Link:
    def __init__(
        self,
        fd: int,
        dispatcher: CommandPort,
        options: CodecOptions,
        frame_gap_s: float,
        held_frames: int = 16,
        clock: Callable[[], float] = time.monotonic,
        *,
        backlog_limit: int = 4096,
        read_size: int = 4096,
        retry_s: float = 0.02,
        drain_s: float = 0.5,
        on_hangup: Callable[[], None] | None = None,
        device: Device | None = None,
        watch: SilenceWatch | None = None,
        backoff: Backoff | None = None,
        recorder: ByteRecorder | None = None,
    ) -> None:
        self.fd = fd
        self.session = LinkSession(dispatcher, options, frame_gap_s, held_frames, backlog_limit)
        self.clock = clock
        self.read_size = read_size
        self.out_limit = backlog_limit * RESPONSE_LEN
        self.retry_s = retry_s
        self.drain_s = drain_s
        self.on_hangup = on_hangup
        self.device = device
        self.backoff = backoff or Backoff()
        self.watch = watch or SilenceWatch(0.0)
        self._watching = self.watch.enabled
        self._lost_at = 0.0  # when the device went away
        self._next_try = 0.0  # when to try to open it again
        self._attempts = 0  # reopen attempts since it went away
        self._reported: set[int | None] = set()  # reopen errors logged since then
        self.recorder = recorder
        self.counters: Counter[str] = Counter(dict.fromkeys(SHELL_COUNTERS, 0))
        self.processing = LatencyStats(threshold_s=108e-6)
        self.peer_gone = False
        self._out = bytearray()
        self._reading = True
        self._mask = -1  # the PTY's events registered with serve()'s poller
        self._poller = select.poll()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stopped = False
        self.turns = 0

    # -- thread-safe pokes ---------------------------------------------------------
    def poke(self) -> None:
        """Make the loop turn once (the watchdog's liveness probe; any thread)."""
        with contextlib.suppress(BlockingIOError):
            os.write(self._wake_w, b"\0")

    def wake(self) -> None:
        """Make the loop re-check a held WaitMoved (called on motor events)."""
        if self.session.waiting:
            with contextlib.suppress(BlockingIOError):
                os.write(self._wake_w, b"\0")

    def stop(self) -> None:
        """End :meth:`serve` at its next turn, or at once if it has not started (from any
        thread or a signal handler; a stop before :meth:`serve` is not forgotten)."""
        self._stopped = True
        with contextlib.suppress(BlockingIOError):
            os.write(self._wake_w, b"\1")

    @property
    def signal_fd(self) -> int:
        """The wake-up pipe's write end, for ``signal.set_wakeup_fd``: the C-level signal
        handler writes a byte there, so a signal wakes :meth:`serve`'s ``poll()`` even when
        its Python handler (which calls :meth:`stop`) cannot run before the loop sleeps."""
        return self._wake_w

    # -- the loop --------------------------------------------------------------------
    def serve(self) -> None:
        """Serve until :meth:`stop`.

        A signal's Python handler runs in the main thread only between bytecodes: when the
        signal arrives just before this loop's ``poll()`` (or is taken by another thread),
        the handler runs only once ``poll()`` returns, and an idle link with the host's port
        open has no timeout. With :attr:`signal_fd` as the signal wake-up descriptor the
        signal's own byte ends that ``poll()``, and the handler runs right after it."""
        poller = self._poller = select.poll()
        poller.register(self._wake_r, POLLIN)
        self._mask = -1
        while not self._stopped:
            self.turn(poller)
            self.turns += 1  # the watchdog's evidence that the loop is not hung
        self._drain()

    def turn(self, poller: select.poll) -> None:
        """One turn of the loop: answer what is due, write, wait, read or watch the silence."""
        session, fd = self.session, self.fd
        if session.waiting:
            session.poll(self.clock())
        if self._watching:
            now = self.clock()
            self.watch.hold(session.waiting, now)
            self.watch.check(now)
        self._flush()
        if self.peer_gone:
            if self.device is not None:
                self._look_for_device()
            else:
                self._look_for_peer()
            return
        reading = session.wants_input() and len(self._out) < self.out_limit
        if reading != self._reading:
            self._reading = reading
            if not reading:
                self.counters["backpressure"] += 1
        mask = (POLLIN if reading else 0) | (POLLOUT if self._out else 0)
        if mask != self._mask:  # a new mask makes poll() rebuild its descriptor array
            self._mask = mask
            poller.register(fd, mask)
        t_enter = self.clock()
        events = 0
        for ready, what in poller.poll(self._timeout_ms(t_enter, reading)):
            if ready == fd:
                events = what
            else:  # the wake-up pipe
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 4096)
        if events & POLLIN:
            self._read(None)
        elif events & POLLGONE:
            self._hangup("closed")
        elif reading:
            self._read(t_enter)

    def _deadline(self) -> float | None:
        """When the loop must turn at the latest: a held WaitMoved's timeout, the silence."""
        deadline = self.session.deadline()
        if self._watching:
            silence = self.watch.deadline()
            if silence is not None and (deadline is None or silence < deadline):
                deadline = silence
        return deadline

    def _timeout_ms(self, now: float, reading: bool) -> float | None:
        deadline = self._deadline()
        gap = self.session.gap_left() if reading else None
        if gap is None:
            if deadline is None:
                return None
            left = deadline - now
        else:
            left = gap if deadline is None else min(gap, deadline - now)
        return max(0.0, left) * 1000.0

    def _read(self, watched_since: float | None) -> None:
        """Read what is there. With ``watched_since`` the poll saw no input: a read that finds
        nothing confirms that the line was silent from then until the clock was read."""
        now = self.clock()
        try:
            data = os.read(self.fd, self.read_size)
        except (BlockingIOError, InterruptedError):
            self.counters["read_eagain"] += 1
            if watched_since is not None:
                self.session.idle(now - watched_since)
            return
        except OSError as exc:
            self._hangup("closed" if exc.errno == errno.EIO else f"read failed: {exc}")
            return
        if not data:  # end of file: nobody is on the other side
            self._hangup("closed")
            return
        self._received(data, now)
        if self._flush():
            self.processing.record_ns(round((self.clock() - now) * 1e9))

    def _flush(self) -> bool:
        """Write what the descriptor takes without blocking; True if anything new was queued."""
        data = self.session.take_output()
        if data:
            if self.peer_gone:
                self.counters["responses_dropped"] += len(data) // RESPONSE_LEN
                return False
            self._out += data
        out = self._out
        while out:
            try:  # a bytearray is written as it is, without a copy, when it is not too long
                n = os.write(self.fd, out if len(out) <= WRITE_MAX else out[:WRITE_MAX])
            except BlockingIOError:
                self.counters["write_eagain"] += 1
                break
            except InterruptedError:
                continue
            except OSError as exc:
                self._hangup("closed" if exc.errno == errno.EIO else f"write failed: {exc}")
                break
            if self.recorder is not None:
                self.recorder.sent(bytes(out[:n]), self.clock())
            del out[:n]
        return bool(data)

    def _hangup(self, why: str) -> None:
        if self.peer_gone:
            return
        self.peer_gone = True
        if self.device is not None:
            if why != "closed":
                self.counters["link_errors"] += 1
            self._lose_device("it hung up" if why == "closed" else why)
        elif why == "closed":
            self.counters["peer_closed"] += 1
            log.info("the host closed the port; serving again when it is reopened")
        else:
            self.counters["link_errors"] += 1
            log.error("link: %s; retrying every %.0f ms", why, self.retry_s * 1000)
        self.counters["hangup_partial_bytes"] += self.session.peer_gone()
        self.counters["responses_dropped"] += len(self._out) // RESPONSE_LEN
        self._out.clear()
        if self.on_hangup is not None:
            self.on_hangup()

    def _look_for_peer(self) -> None:
        """Peer gone: wait ``retry_s`` (or a wake-up), then see whether the port is open."""
        deadline = self._deadline()
        wait = self.retry_s
        if deadline is not None:
            wait = max(0.0, min(wait, deadline - self.clock()))
        with contextlib.suppress(InterruptedError):
            select.select([self._wake_r], [], [], wait)
        with contextlib.suppress(BlockingIOError):
            os.read(self._wake_r, 4096)
        probe = select.poll()
        probe.register(self.fd, POLLIN)
        events = dict(probe.poll(0)).get(self.fd, 0)
        if events & POLLGONE and not events & POLLIN:
            return
        try:
            data = os.read(self.fd, self.read_size) if events & POLLIN else b""
        except (BlockingIOError, InterruptedError):
            data = b""
        except OSError:
            return
        if events & POLLGONE and not data:
            return
        self.peer_gone = False
        self.counters["peer_reopened"] += 1
        log.info("the port is open again")
        if data:
            self._received(data, self.clock())

    def _received(self, data: bytes, now: float) -> None:
        """A run of bytes read at ``now``: it keeps the link alive, the trace records it,
        the session takes it."""
        self.counters["reads"] += 1
        if self._watching:
            self.watch.heard(now)
        if self.recorder is not None:
            self.recorder.received(data, now)
        self.session.receive(data, now)

    # -- a serial device that went away --------------------------------------------------
    def _lose_device(self, why: str) -> None:
        """Close the dead descriptor; open the path again from ``backoff``'s first delay."""
        assert self.device is not None
        path = self.device.path
        with contextlib.suppress(KeyError, ValueError):
            self._poller.unregister(self.fd)
        self._mask = -1
        self.device.close()
        self.fd = -1
        self.counters["device_lost"] += 1
        self._lost_at = now = self.clock()
        self._attempts = 0
        self._reported = set()
        self.backoff.reset()
        self._next_try = now + self.backoff.delay()
        log.warning(
            "serial device %s is gone (%s); motors, positions and held frames are "
            "kept; opening %s again when it is back (first try in %.0f ms, then "
            "doubling up to every %.0f ms)",
            path,
            why,
            path,
            self.backoff.first_s * 1000,
            self.backoff.max_s * 1000,
            extra={"DEVICE": path, "EVENT": "device_lost"},
        )

    def _look_for_device(self) -> None:
        """Device gone: wait for the next attempt (or a deadline, a wake-up), then try."""
        assert self.device is not None
        now = self.clock()
        wait = self._next_try - now
        deadline = self._deadline()
        if deadline is not None:
            wait = min(wait, deadline - now)
        if wait > 0:
            with contextlib.suppress(InterruptedError):
                select.select([self._wake_r], [], [], wait)
        with contextlib.suppress(BlockingIOError):
            os.read(self._wake_r, 4096)
        now = self.clock()
        if now < self._next_try or self._stopped:
            return
        self._attempts += 1
        self.counters["reopen_attempts"] += 1
        try:
            fd = self.device.open()
        except DeviceError as exc:
            self._next_try = now + self.backoff.delay()
            if exc.errno in NOT_BACK or exc.errno in self._reported:
                log.debug("%s; trying again in %.0f ms", exc, (self._next_try - now) * 1000)
            else:  # there, but not usable: the user must act (it is retried all the same)
                self._reported.add(exc.errno)
                log.warning(
                    "%s; trying again (every %.0f ms at most)",
                    exc,
                    self.backoff.max_s * 1000,
                    extra={"DEVICE": self.device.path},
                )
            return
        self.fd = fd
        self._mask = -1
        self.peer_gone = False
        self.counters["device_reopened"] += 1
        log.info(
            "serial device %s is back after %.1f s (%d attempts): serving again",
            self.device.path,
            now - self._lost_at,
            self._attempts,
            extra={"DEVICE": self.device.path, "EVENT": "device_back"},
        )

    def _drain(self) -> None:
        """After stop(): give unsent responses at most ``drain_s`` to leave."""
        if self.fd < 0:  # a serial device that is gone: nothing can leave
            return
        end = self.clock() + self.drain_s
        poller = select.poll()
        poller.register(self.fd, POLLOUT)
        self._flush()
        while self._out and not self.peer_gone:
            left = end - self.clock()
            if left <= 0:
                self.counters["responses_dropped"] += len(self._out) // RESPONSE_LEN
                log.warning("shutdown: %d unsent response bytes dropped", len(self._out))
                self._out.clear()
                break
            poller.poll(left * 1000.0)
            self._flush()

    def status(self) -> dict[str, object]:
        session = self.session
        counts: dict[str, object] = dict(session.counters)
        counts.update(self.counters)
        counts.update(self.watch.counters)
        peer = "open"
        if self.peer_gone:
            peer = "gone" if self.device is not None else "closed"
        return {
            "counters": counts,
            "processing": self.processing.summary(),
            "held": session.held,
            "waiting": session.waiting,
            "peer": peer,
            "unsent_bytes": len(self._out),
            "recent": session.describe_recent(),
        }

    def close(self) -> None:
        os.close(self._wake_r)
        os.close(self._wake_w)
