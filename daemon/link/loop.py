"""The link's loop: poll, read, write, around the pure session (daemon/link/session.py).

One loop that every byte crosses, whose states (reading, holding back, no host, a host's
session ending, a device away) decide together what each turn waits for; what could stand
apart does: the session, the silence watch (silence.py), the device's return (devwatch.py),
the PTY's slave (ports.py), the ends of sessions in the counters and the log
(session_end.py), what a status reader gets (report.py), all in daemon/link/.

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
- **A host's session ends** when it closes the PTY (POLLHUP, EIO; or the slave's close
  and a new open reported by ``pty``'s inotify watch, when a host closed the port and
  another opened it before the link looked) or its serial device goes away. Everything
  owed to it is dropped and counted by cause (``responses_dropped_*``; logged a moment
  later, session_end.py): the partial frame, the answers not yet written (``unsent``; on a
  PTY also those the kernel still holds for it, counted and flushed by ``pty``, a
  :class:`~motorctl.daemon.link.ports.PtySlave`, unless nothing was written to that host
  at all), a held WaitMoved's answer (``wait``) and the answers of the frames kept behind
  it (``held``; their commands are never executed: :meth:`LinkSession.end`); on a PTY, what
  it wrote and the link had not read (back pressure leaves it in the kernel) is read out and
  dropped, a StopMove in it carried out (session_end.py): the next host reads only its own.
- **No host on the PTY**: ``pty`` holds the slave side open, so that the master does not
  report POLLHUP over and over; ``poll()`` sleeps until a host writes, and its first bytes
  are read like any others. Any other read or write error (or a PTY whose slave cannot be
  held) is logged, counted and ends the session the same way; the shell then looks every
  ``retry_s`` whether the port works again: the thread never dies.
- **A serial device may go away** (``device``: ``--port``; a USB adapter unplugged, a
  socat PTY torn down), or not be there yet at start. Its descriptor is hung up for good
  (POLLHUP, an empty read, EIO), so the shell closes it, logs the loss once and opens the
  device's *path* again (:class:`~motorctl.daemon.link.devwatch.DeviceReturn`) the moment
  ``notice`` (a :class:`~motorctl.daemon.link.devwatch.PathWatch`: inotify on the folders of the
  path) sees it come back, and on a :class:`~motorctl.daemon.link.serialport.Backoff` schedule
  meanwhile (50 ms after the loss, doubling up to every second) as the fallback; it opens
  it without flushing what the new session sent. Motors and positions are kept; the
  session ends as above.
- **The host's silence** (``watch``: ``[link] timeout_ms``, off by default): every byte
  read tells the :class:`~motorctl.daemon.link.silence.SilenceWatch`; its deadline bounds the
  waits; while the shell does not read (back pressure) the silence does not count, and it
  is checked only after a read found nothing waiting (the gap's rule); when it passes the
  watch stops the motors in motion.
- **Shutdown is bounded.** :meth:`stop` ends the loop at its next turn; unsent responses get
  at most ``drain_s`` to leave.
- **A recorder may listen.** Given one (``motorctld --trace``), every byte run read from the
  host and every run written to it is handed to it with this loop's own clock reading, on
  this thread (seams.py; the daemon's is :mod:`motorctl.daemon.link.recorder`).
- **Processing time** (``processing``): from a read to its answers written, for every read
  that produced answers, whichever way its frames were taken (the session's one-frame path
  or its framer) and whether or not the read began a session.
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

from motorctl.daemon.config.model import LinkConfig
from motorctl.daemon.link.cpu_parts import CpuParts, TimedPort
from motorctl.daemon.link.devwatch import Device, DeviceReturn, Notice
from motorctl.daemon.link.report import report
from motorctl.daemon.link.seams import ByteRecorder, Slave
from motorctl.daemon.link.serialport import Backoff
from motorctl.daemon.link.session import CommandPort, LinkSession
from motorctl.daemon.link.session_end import END_COUNTERS, SessionEnds, read_out
from motorctl.daemon.link.silence import SilenceWatch
from motorctl.motion.latency import LatencyStats
from motorctl.protocol.codec import RESPONSE_LEN, CodecOptions
from motorctl.schema import default_of

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
    *END_COUNTERS,
    "backpressure",
    "device_lost",
    "device_reopened",
    "reopen_attempts",
)


class Link:
    def __init__(
        self,
        fd: int,
        dispatcher: CommandPort,
        options: CodecOptions,
        frame_gap_s: float,
        held_frames: int = default_of(LinkConfig, "held_frames"),
        clock: Callable[[], float] = time.monotonic,
        *,
        backlog_limit: int = 4096,
        read_size: int = 4096,
        retry_s: float = 0.02,
        drain_s: float = 0.5,
        pty: Slave | None = None,
        device: Device | None = None,
        notice: Notice | None = None,
        watch: SilenceWatch | None = None,
        backoff: Backoff | None = None,
        recorder: ByteRecorder | None = None,
        parts: CpuParts | None = None,
    ) -> None:
        """``fd``: the PTY's master (with ``pty``, its slave side), the serial device's
        descriptor (with ``device``; -1: not there yet, served when it appears, ``notice``
        telling when something changes on its path), or any other descriptor. ``parts``: the
        thread's CPU time counted part by part (cpu_parts.py; None: not counted)."""
        self.fd = fd
        self.parts = parts
        port = dispatcher if parts is None else TimedPort(dispatcher, parts)
        self.session = LinkSession(port, options, frame_gap_s, held_frames, backlog_limit)
        self.clock = clock
        self.read_size = read_size
        self.out_limit = backlog_limit * RESPONSE_LEN
        self.retry_s = retry_s
        self.drain_s = drain_s
        self.pty = pty
        self.device = device
        self.watch = watch or SilenceWatch(0.0)
        self._watching = self.watch.enabled
        self.recorder = recorder
        self.counters: Counter[str] = Counter(dict.fromkeys(SHELL_COUNTERS, 0))
        self.away = (  # a device gone (or not there yet): when and how to open it again
            None
            if device is None
            else DeviceReturn(device, notice, backoff or Backoff(), self.counters)
        )
        self.processing = LatencyStats(threshold_s=108e-6)
        self.peer_gone = False
        self._answered = False  # anything written to the host since its session began
        self._out = bytearray()
        self._reading = True
        self._mask = -1  # the PTY's events registered with serve()'s poller
        self._opens: int | None = None  # the PTY slave's opens and closes, registered there
        self.ends = SessionEnds(self.counters, self.clock)
        self._poller = select.poll()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stopped = False
        self.turns = 0
        self.waits = 0  # counted before each poll(): a turn's changes so far are done
        if self.away is not None and fd < 0:  # not there at start: served when it appears
            self.peer_gone = True
            self.away.awaited(self.clock())
        elif pty is not None:  # no host yet: hold the slave until one writes
            self.peer_gone = True
            pty.hold()

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
        self._opens = self.pty.events_fd if self.pty is not None else None
        if self._opens is not None:  # watched while a session is open
            poller.register(self._opens, 0 if self.peer_gone else POLLIN)
        self._mask = -1
        while not self._stopped:
            self.turn(poller)
            self.turns += 1  # the watchdog's evidence that the loop is not hung
        self.ends.say()
        self._drain()

    def turn(self, poller: select.poll) -> None:
        """One turn of the loop: answer what is due, write, wait, read, watch the silence."""
        session = self.session
        if (
            self._mask == POLLIN  # reading, nothing was left to write
            and session.wait is None  # so nothing is held or owed: no back pressure
            and not (self._out or self.peer_gone or self._watching or session.framer.pending)
        ):  # the usual turn: nothing due, owed or partial; what _listen and _timeout_ms say
            reading = True
            t_enter = self.clock()
            events, opened = self._wait(poller, self.ends.bound(t_enter, None))
        else:
            waiting = session.wait is not None
            if waiting:
                session.poll(self.clock())
            if self._watching:
                self.watch.hold(session.wait is not None, self.clock())
            if waiting or self._out:  # answers only come from a read (written then) or a wait
                self._flush()
            if self.peer_gone and not (self.pty is not None and self.pty.held):
                if self.device is not None:
                    self._look_for_device()
                else:
                    self._look_for_peer()
                if self._watching:
                    self.watch.check(self.clock())
                return
            reading = self._listen(poller)
            t_enter = self.clock()
            timeout = self.ends.bound(t_enter, self._timeout_ms(t_enter, reading))
            events, opened = self._wait(poller, timeout)
        # The slave's opens and closes first: a host that closed the port and opened it
        # again before this poll (no POLLHUP seen) has ended its session all the same, and
        # the bytes it sends since are the next session's. What is there to read now is
        # taken as the new host's (the old one's were read as they came, unless it wrote
        # and closed within the moment the new one opened and wrote: that cannot be told
        # apart). The port's own events are looked at from the next turn on (holding the
        # slave has changed them).
        if opened and self._reopened():
            self._hangup("closed", reopened=True)
            self._read(None)  # the new host's first bytes, often there already
            return
        if events & POLLIN:
            self._read(None)
        elif events & POLLGONE:
            if self.peer_gone and self.pty is not None:  # the held slave failed us
                self.pty.release()  # look every retry_s from now on
            else:
                self._hangup("closed")
        elif reading:
            self._read(t_enter)
        if self._watching:  # after the read: bytes that waited in the kernel were heard
            self.watch.check(self.clock())

    def _listen(self, poller: select.poll) -> bool:
        """Whether to read this turn: not while the host has too much to read back (back
        pressure; the silence does not count meanwhile). The port's events are registered
        with ``poller`` accordingly."""
        reading = self.session.wants_input() and len(self._out) < self.out_limit
        if reading != self._reading:
            self._reading = reading
            if not reading:
                self.counters["backpressure"] += 1
            if self._watching:
                self.watch.listening(reading, self.clock())
        mask = (POLLIN if reading else 0) | (POLLOUT if self._out else 0)
        if mask != self._mask:  # a new mask makes poll() rebuild its descriptor array
            self._mask = mask
            poller.register(self.fd, mask)
        return reading

    def _wait(self, poller: select.poll, timeout: float | None) -> tuple[int, bool]:
        """``poll()``: the port's events, and whether the PTY's slave was opened or closed
        (a wake-up's bytes are taken)."""
        events = 0
        opened = False
        parts = self.parts
        if parts is not None:
            parts.mark("bookkeeping")
        self.waits += 1  # after what this turn changed before its wait (a reader's moment)
        ready_list = poller.poll(timeout)
        if parts is not None:
            parts.mark("poll")
        for ready, what in ready_list:
            if ready == self.fd:
                events = what
            elif ready == self._wake_r:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 4096)
            else:  # the slave was opened or closed
                opened = True
        return events, opened

    def _deadline(self) -> float | None:
        """When the loop must turn at the latest: a held WaitMoved's timeout, the silence."""
        deadline = self.session.deadline()
        if self._watching:
            silence = self.watch.deadline()
            if silence is not None and (deadline is None or silence < deadline):
                deadline = silence
        return deadline

    def _timeout_ms(self, now: float, reading: bool) -> float | None:
        session = self.session
        if session.wait is None and not self._watching and not session.framer.pending:
            return None  # the usual turn: nothing due, nothing partial
        deadline = self._deadline()
        lefts = [] if deadline is None else [deadline - now]
        if reading and (gap := session.gap_left()) is not None:
            lefts.append(gap)
        return max(0.0, min(lefts)) * 1000.0 if lefts else None

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
        if self._reopened():  # these bytes came after a host closed the port and another
            self._hangup("closed", reopened=True)  # opened it: the next session's (turn())
        if self.parts is not None:
            self.parts.mark("read")
        self._take(data, now)

    def _reopened(self) -> bool:
        """Whether, during the open session, the PTY was closed by a host and opened again
        (its events are taken in any case). Asked before the bytes read are taken: a host's
        open is reported before anything it writes can be read, so no new host's byte
        joins the old session, however the poll and the read fell."""
        pty = self.pty
        if pty is None:
            return False
        watched = pty.events_fd is not None
        reopened = watched and pty.reopened()
        if self._opens is not None and not watched:
            self._poller.unregister(self._opens)  # no longer watched: before its number
            self._opens = None  # can be reused
        return reopened and not self.peer_gone

    def _take(self, data: bytes, now: float) -> None:
        """Bytes read at ``now``: to the session, and their answers to the port; the
        processing time of every read that produced answers is recorded."""
        opening = self.peer_gone
        if opening:  # a new host's first bytes (found by a poll or a look)
            self.peer_gone = False
            self._answered = False
            if self.pty is not None:
                self.pty.release()  # before its answers (PtySlave.release)
        self.counters["reads"] += 1  # they keep the link alive, the trace records them
        if self._watching:
            self.watch.heard(now)
        if self.recorder is not None:
            self.recorder.received(data, now)
        answer = self.session.answer(data, now)  # the usual read: one frame, its answer
        if answer is None:
            self.session.receive(data, now)
            answered = self._flush()
        else:
            self._out += answer
            self._send("encode")
            answered = True
        if answered:
            self.processing.record_ns(round((self.clock() - now) * 1e9))
        if opening:  # the rest of its session's start, after its first answers
            self._open_session()

    def _flush(self) -> bool:
        """Write what the descriptor takes without blocking; True if anything new was queued."""
        data = self.session.take_output()
        if data:
            if self.peer_gone:  # nothing is owed to nobody; kept for safety
                self.ends.drop("unsent", len(data) // RESPONSE_LEN)
                return False
            self._out += data
        if self._out:
            self._send("encode" if data else None)
        return bool(data)

    def _send(self, taken: str | None) -> None:
        """Write what the descriptor takes of the output, without blocking; the CPU count's
        part ``taken`` ends first (answers just taken: "encode"), then ``write``."""
        out = self._out
        parts = self.parts
        if parts is not None and taken is not None:
            parts.mark(taken)
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
            self._answered = True
            if self.recorder is not None:
                self.recorder.sent(bytes(out[:n]), self.clock())
            del out[:n]
        if parts is not None and taken is not None:
            parts.mark("write")

    def _hangup(self, why: str, reopened: bool = False) -> None:
        """The host's side is gone (``why``: "closed", or the error): its session ends.
        ``reopened``: the PTY's slave was opened again since: a new host has it. A close
        is counted (``peer_closed``) once the session's end is done: a status reader that
        sees it sees what the end dropped; a new host then finds nothing of the old session."""
        if self.peer_gone:
            return
        self.peer_gone = True
        how = "the host closed the port" if why == "closed" else "the port failed"
        if self.device is not None:
            how = "its serial device went away"
            self.counters["link_errors"] += int(why != "closed")
            self._lose_device("it hung up" if why == "closed" else why)
        elif why != "closed":
            self.counters["link_errors"] += 1
            log.error("link: %s; retrying every %.0f ms", why, self.retry_s * 1000)
        self._end_session(how, reopened, closed=self.device is None and why == "closed")

    def _end_session(self, how: str, reopened: bool = False, closed: bool = False) -> None:
        """Drop and count what was owed to the host whose session ended (``how``).
        ``reopened``: a new host has the PTY; if the old one was written nothing, nothing
        of it is in the slave's input, and the new host's session begins at once.
        ``closed``: a close, counted once the end is done, before a new host is answered."""
        pty, unread, rest = self.pty, b"", b""
        if pty is not None and self.device is None and not reopened:  # what it wrote, unread
            unread, rest, reopened = read_out(self.fd, pty.reopened)
        ended = self.session.end(unread)
        unsent = len(self._out)  # bytes; a part-sent answer's first ones in the kernel
        self._out.clear()
        at_once = False  # the new host's session begins now, nothing held
        if pty is not None and self.device is None:
            at_once = reopened and not self._answered
            if not at_once:  # left unread in the kernel (looked for if anything was written)
                unsent += pty.hold(self._answered)
        self.ends.ended(how, ended, ended.unsent + -(-unsent // RESPONSE_LEN))
        self.counters["peer_closed"] += int(closed)
        if at_once and pty is not None:
            pty.release()  # its closes are accounted for
            self._open_session()  # the new host's (nothing written to it yet)
        elif self._opens is not None:  # no session: a host's open need not wake the loop
            self._poller.modify(self._opens, 0)
        if rest:  # read out after a new host opened the port: its session's
            self._take(rest, self.clock())

    def _open_session(self) -> None:
        """A host is there again (a new session): its opens and closes are watched again
        (the slave held meanwhile was let go before its first answers, :meth:`_take`)."""
        self.peer_gone = False
        if self._opens is not None:
            self._poller.modify(self._opens, POLLIN)
        self.counters["peer_reopened"] += 1
        log.debug("a host opened the port")

    def _look_for_peer(self) -> None:
        """No host, and no held slave to wait on: wait ``retry_s`` (or a wake-up), then see
        whether the port works again."""
        deadline = self._deadline()
        wait = self.retry_s
        if deadline is not None:
            wait = max(0.0, min(wait, deadline - self.clock()))
        with contextlib.suppress(InterruptedError):
            select.select([self._wake_r], [], [], wait)
        with contextlib.suppress(BlockingIOError):
            os.read(self._wake_r, 4096)
        if self._stopped:
            return
        if self.pty is not None:
            self.ends.drop("unsent", -(-self.pty.hold() // RESPONSE_LEN))
            if self.pty.held:
                return  # held again: the next turns wait for the host's first byte
        probe = select.poll()
        probe.register(self.fd, POLLIN)
        events = dict(probe.poll(0)).get(self.fd, 0)
        if events & POLLGONE and not events & POLLIN:
            return
        now = self.clock()
        try:
            data = os.read(self.fd, self.read_size) if events & POLLIN else b""
        except (BlockingIOError, InterruptedError):
            data = b""
        except OSError:  # still failing: counted once, when it began
            return
        if events & POLLGONE and not data:
            return
        if data:
            self._take(data, now)  # its session begins, once they are answered
        else:
            self._open_session()

    # -- a serial device that went away (or is not there yet) ------------------------------
    def _lose_device(self, why: str) -> None:
        """Close the dead descriptor; open the path again when it is back."""
        with contextlib.suppress(KeyError, ValueError):
            self._poller.unregister(self.fd)
        self._mask = -1
        assert self.away is not None
        self.away.lost(why, self.clock())  # closes the device
        self.fd = -1

    def _look_for_device(self) -> None:
        """Device gone: wait for news on its path, the next attempt, a deadline or a
        wake-up; then try, if it is time or something changed."""
        away = self.away
        assert away is not None
        now = self.clock()
        wait = away.wait_s(now)
        deadline = self._deadline()
        if deadline is not None:
            wait = min(wait, deadline - now)
        ready: list[int] = []
        with contextlib.suppress(InterruptedError):
            ready = select.select([self._wake_r, *away.fds], [], [], max(0.0, wait))[0]
        with contextlib.suppress(BlockingIOError):
            os.read(self._wake_r, 4096)
        if self._stopped:
            return
        fd = away.look(ready, self.clock())
        if fd is not None:
            self.fd = fd
            self._mask = -1
            self.peer_gone = False

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
                self.ends.drop("shutdown", -(-len(self._out) // RESPONSE_LEN))
                log.warning("shutdown: %d unsent response bytes dropped", len(self._out))
                self._out.clear()
                break
            poller.poll(left * 1000.0)
            self._flush()

    def status(self) -> dict[str, object]:
        """What a status reader gets (any thread: it only copies; report.py)."""
        return report(self, len(self._out))

    def close(self) -> None:
        os.close(self._wake_r)
        os.close(self._wake_w)
        if self.pty is not None:
            self.pty.close()
        if self.away is not None:
            self.away.close()
