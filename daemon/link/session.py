"""The link session: the protocol side of the link, pure (no file descriptors, no clock).

Bytes and timestamps go in (:meth:`LinkSession.receive`, :meth:`LinkSession.idle`,
:meth:`LinkSession.poll`); response bytes come out (:meth:`LinkSession.take_output`) in the
order their frames arrived, exactly one per complete frame. Commands are executed through a
narrow port (the dispatcher's ``handle``/``wait_begin``/``wait_poll``). The select loop in
:mod:`motorctl.daemon.link.loop` is a thin shell around it.

Owned by the link thread; nothing here blocks except the port's calls (the engine lock, and
a hard StopMove's bounded wait for the executor's confirmation).

The rules (PROTOCOL.md §2, §4):
- Framing by watched silence (:class:`motorctl.protocol.framing.Framer`).
- A frame that fails its checks is answered E1 in its turn and never executed.
- A WaitMoved holds the responses of later frames until it is answered. Later frames are kept
  in arrival order; up to ``held_limit`` of them take a place in the held-frame buffer, each
  one beyond it is answered E0 in its turn and not executed. A frame that fails its checks
  takes a place like any other (PROTOCOL.md §4 exempts only StopMove) and is answered E1 in
  its turn; beyond the limit it is answered E1 all the same (E1 for the frame precedes E0,
  §5). A StopMove is executed on arrival (its answer decided then) and answered in its turn;
  it never takes a place and is never refused for lack of room. When the WaitMoved is
  answered the kept frames run in order; a WaitMoved among them is taken up then (its
  TIMEOUT counts from that moment) and holds again.
- The host's session ends (:meth:`LinkSession.end`: the shell saw the host close the PTY, or
  the serial device go away). Nothing owed to it is ever given to the next host: the
  partial frame, the answers not yet taken, a held WaitMoved's answer and the kept frames'
  answers are dropped, and the kept commands are discarded, never executed (their host is
  gone and was waiting for the motion to end before it sent them; a StopMove among them was
  executed on arrival). The motors go on with what they were doing (docs/protocol.md,
  "When a host goes away").
"""

from __future__ import annotations

import logging
from collections import Counter, deque
from dataclasses import dataclass
from typing import Protocol

from motorctl.daemon.dispatcher import Wait
from motorctl.protocol.codec import (
    RESPONSE_LEN,
    CodecOptions,
    Command,
    ErrorCode,
    FrameError,
    Response,
    ResponseError,
    StopMove,
    WaitMoved,
    decode_command,
    decode_response,
    describe,
    describe_answer,
    encode_response,
)
from motorctl.protocol.framing import Framer

log = logging.getLogger("motorctl.link")

# Every counter exists from the start, so another thread may copy them at any time.
COUNTERS = (
    "bytes_in",
    "frames",
    "frames_good",
    "checksum_errors",
    "unknown_errors",
    "padding_errors",
    "length_errors",
    "responses",
    "gap_discards",
    "held_max",
    "held_overflow",
    "stops_while_held",
    "waits_taken_up",
    "internal_errors",
    "held_discarded",
    *(f"sent_{code.short}" for code in ErrorCode),
)
_SENT = {code.value: f"sent_{code.short}" for code in ErrorCode}
CACHE_LIMIT = 256  # frames and responses remembered; forgotten all at once when full
RECENT = 16  # the last frames and answers kept for the status (:meth:`LinkSession.recent`)


#: the answer recorded in :meth:`LinkSession.recent` for a frame whose answer was dropped
#: when its host's session ended
DROPPED = b""


@dataclass(frozen=True)
class Ended:
    """What an ended session left behind, all of it dropped (:meth:`LinkSession.end`)."""

    partial_bytes: int  # bytes of an incomplete frame
    unsent: int  # answers decided but not yet taken by the shell
    wait: int  # 1 when a WaitMoved's answer was held
    held: int  # answers owed to the frames kept behind it (decided or not)
    discarded: int  # of those, commands never executed
    unread_frames: int = 0  # frames the host wrote and the daemon had not read, dropped
    unread_stops: int = 0  # of those, StopMoves, carried out

    @property
    def answers(self) -> int:
        return self.unsent + self.wait + self.held


class CommandPort(Protocol):
    """What the session needs from the dispatcher, and nothing more."""

    def handle(self, cmd: Command) -> Response: ...

    def wait_begin(self, cmd: WaitMoved, now: float) -> Response | Wait: ...

    def wait_poll(self, wait: Wait, now: float) -> Response | None: ...

    def refused(
        self,
        code: ErrorCode,
        reason: str,
        command: Command | None = None,
        frame: bytes | None = None,
    ) -> None:
        """An error the session answers itself, with its reason (kept and journalled)."""
        ...


class LinkSession:
    """Frames in, responses out, in order; WaitMoved holding and the held-frame buffer."""

    def __init__(
        self,
        port: CommandPort,
        options: CodecOptions,
        frame_gap_s: float,
        held_limit: int = 16,
        backlog_limit: int = 4096,
    ) -> None:
        self.port = port
        self.options = options
        self.framer = Framer(frame_gap_s)
        self.held_limit = held_limit
        self.backlog_limit = backlog_limit
        self.counters: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))
        self.wait: Wait | None = None
        # Frames behind the held WaitMoved: a command still to execute, None for a frame that
        # failed its checks (answered E1 in its turn), or an answer decided on arrival that
        # takes no place (E0 beyond the limit, a StopMove's), already encoded.
        self._held: deque[Command | bytes | None] = deque()
        self._held_places = 0  # commands and Nones in _held (they take a place in the buffer)
        self._out = bytearray()
        # times the answers were taken for writing: counted once everything their frames
        # changed is done, before the host can read them (a status reader's sign that its
        # own command's changes are there: daemon/status/document.py)
        self.outputs = 0
        # A host polls with the same few frames and gets the same few answers: both
        # translations are remembered (commands and responses are immutable; a frame
        # that fails its checks is not remembered and is checked again each time).
        self._decoded: dict[bytes, Command] = {}
        self._encoded: dict[tuple[bool, bytes], bytes] = {}
        # The last frames (number, arrival time, bytes) and answers (number, bytes): answer n
        # is the answer to frame n, as responses go out in the order of their frames.
        self._frames_seen: deque[tuple[int, float, bytes]] = deque(maxlen=RECENT)
        self._answers_seen: deque[tuple[int, bytes]] = deque(maxlen=RECENT)
        self._answer_no = 0  # the number of the last answer (or dropped one)
        # their words, remembered by the threads that read the status (never the link's)
        self._described: dict[tuple[bytes, bytes | None], tuple[str, str | None]] = {}

    # -- what the shell asks ------------------------------------------------------------
    @property
    def waiting(self) -> bool:
        return self.wait is not None

    @property
    def held(self) -> int:
        return len(self._held)

    @property
    def owed(self) -> int:
        """Responses owed to the host: held ones and ones not yet taken for writing."""
        return len(self._held) + len(self._out) // RESPONSE_LEN

    def wants_input(self) -> bool:
        """False while too many responses are owed: the shell stops reading (back pressure on
        the host) rather than let memory grow without bound."""
        return self.owed < self.backlog_limit

    def deadline(self) -> float | None:
        """When :meth:`poll` must run at the latest (a held WaitMoved's timeout)."""
        return None if self.wait is None else self.wait.deadline

    def gap_left(self) -> float | None:
        """Silence still to be watched before the partial frame is dropped."""
        return self.framer.gap_left()

    def recent(self) -> list[tuple[float, bytes, bytes | None]]:
        """The last frames, oldest first: (arrival time, frame, its answer or None while it
        is owed; :data:`DROPPED` when it went with its host's session). Any thread: each
        deque is copied in one C call under the GIL."""
        frames = self._frames_seen.copy()
        answers = dict(self._answers_seen.copy())
        return [(t, frame, answers.get(n)) for n, t, frame in frames]

    def describe_recent(self) -> list[dict[str, object]]:
        """:meth:`recent` for the status: ``at_s`` (the link's clock), ``frame`` and
        ``answer`` as hex (``answer`` None while owed, "" when dropped with its host's
        session), ``command`` and ``result`` in words (``result`` None while owed).
        Decoding is the caller's work (the status thread)."""
        out: list[dict[str, object]] = []
        described = self._described  # the status readers' own cache (dict ops are atomic)
        for t, frame, answer in self.recent():
            words = described.get((frame, answer))
            if words is None:
                words = self._describe(frame, answer)
                if len(described) >= CACHE_LIMIT:
                    described.clear()
                described[(frame, answer)] = words
            out.append(
                {
                    "at_s": t,
                    "frame": frame.hex(" "),
                    "command": words[0],
                    "answer": None if answer is None else answer.hex(" "),
                    "result": words[1],
                }
            )
        return out

    def _describe(self, frame: bytes, answer: bytes | None) -> tuple[str, str | None]:
        cmd: Command | None
        try:
            cmd = decode_command(frame, self.options)
            command = describe(cmd)
        except FrameError as exc:
            cmd, command = None, f"bad frame ({exc.reason}): {exc}"
        result: str | None = None
        if answer == DROPPED:
            result = "not sent: its host's session ended"
        elif answer is not None:
            try:
                result = describe_answer(cmd, decode_response(answer, self.options))
            except ResponseError as exc:  # not one of ours: say so, never raise
                result = f"undecodable answer: {exc}"
        return command, result

    def take_output(self) -> bytes:
        """The response bytes ready to send, in order; the session forgets them."""
        if not self._out:
            return b""
        self.outputs += 1
        data = bytes(self._out)
        self._out.clear()
        return data

    # -- what the shell tells ------------------------------------------------------------
    def receive(self, data: bytes, now: float) -> None:
        """Bytes read at ``now``, contiguous with any partial frame."""
        if not data:
            return
        self.counters["bytes_in"] += len(data)
        if self.wait is None and not self.framer.pending:
            cmd = self._decoded.get(data)
            if cmd is not None and not isinstance(cmd, WaitMoved):
                self._out += self._one_frame(cmd, data, now)
                return
        for frame in self.framer.feed(data):
            self._on_frame(frame, now)

    def answer(self, data: bytes, now: float) -> bytes | None:
        """:meth:`receive` and :meth:`take_output` in one, for the usual read of a host that
        waits for each answer: ``data`` one whole frame it sent before (no WaitMoved),
        nothing partial, nothing held, nothing untaken. Its answer, taken for writing; None
        for any other read, and then nothing was done (:meth:`receive` it). Every
        microsecond this process spends per command shows in the host's round trip
        (docs/timing.md); tests hold this path and the framer's to the same answers and
        counts."""
        if self.wait is not None or self._out or self.framer.pending:
            return None
        cmd = self._decoded.get(data)
        if cmd is None or isinstance(cmd, WaitMoved):
            return None
        self.counters["bytes_in"] += len(data)
        out = self._one_frame(cmd, data, now)
        self.outputs += 1  # as take_output(): everything the frame changed is done
        return out

    def _one_frame(self, cmd: Command, data: bytes, now: float) -> bytes:
        """What _on_frame, _execute and _emit do for a whole frame decoded before (no
        WaitMoved, nothing held), without the framer and their calls: its answer, counted
        as emitted (not put in the output)."""
        counters = self.counters
        frames = counters["frames"] + 1
        counters["frames"] = frames
        counters["frames_good"] += 1
        self._frames_seen.append((frames, now, data))
        try:
            resp = self.port.handle(cmd)
        except Exception:
            resp = self._failed(cmd)
        out = self._encode(resp)
        self._count_answer(out)
        return out

    def idle(self, seconds: float) -> None:
        """The shell watched the line, ready to read, and no byte came for ``seconds``."""
        if self.framer.idle(seconds):
            self.counters["gap_discards"] += 1

    def poll(self, now: float) -> None:
        """Re-check a held WaitMoved (a motor event, or its deadline)."""
        wait = self.wait
        if wait is None:
            return
        result = self.port.wait_poll(wait, now)
        if result is None:
            return
        self.wait = None
        self._emit(result)
        self._release(now)

    def end(self, unread: bytes = b"") -> Ended:
        """The host's session ended (it closed the port, or its device went away): what is
        owed to it is dropped, so that the next host reads only its own answers. The partial
        frame, the answers not yet taken, a held WaitMoved and the frames kept behind it go;
        the kept commands are never executed (a StopMove among them already was). ``unread``:
        what the host wrote that had not been read when its session ended (back pressure
        leaves up to the kernel's buffers of it), read out by the shell: its frames
        (framed on from the partial frame) are dropped unanswered and never executed, but
        a StopMove among them, carried out now (a StopMove is never lost). The next frame
        starts a session with nothing held."""
        held = self._held
        discarded = sum(1 for item in held if not isinstance(item, bytes) and item is not None)
        kept, unsent, wait = len(held), len(self._out) // RESPONSE_LEN, int(self.wait is not None)
        self.wait = None
        held.clear()
        self._held_places = 0
        self._out.clear()
        unread_frames = self.framer.feed(unread)
        stops = [cmd for cmd in map(self._command_of, unread_frames) if isinstance(cmd, StopMove)]
        for stop in stops:
            self._execute(stop)  # its answer goes nowhere
        ended = Ended(
            partial_bytes=self.framer.reset(),
            unsent=unsent,
            wait=wait,
            held=kept,
            discarded=discarded,
            unread_frames=len(unread_frames),
            unread_stops=len(stops),
        )
        self.counters["held_discarded"] += discarded
        # the frames whose answers go are marked as such (the status's last frames)
        frames = self.counters["frames"]
        for n in range(max(self._answer_no, frames - RECENT) + 1, frames + 1):
            self._answers_seen.append((n, DROPPED))
        self._answer_no = frames
        return ended

    # -- frames -----------------------------------------------------------------------------
    def _command_of(self, frame: bytes) -> Command | None:
        """The command of ``frame``, None if it fails its checks (not counted)."""
        try:
            return self._decoded.get(frame) or decode_command(frame, self.options)
        except FrameError:
            return None

    def _on_frame(self, frame: bytes, now: float) -> None:
        counters = self.counters
        counters["frames"] += 1
        self._frames_seen.append((counters["frames"], now, frame))
        cmd: Command | None = self._decoded.get(frame)
        if cmd is None:
            try:
                cmd = decode_command(frame, self.options)
            except FrameError as exc:
                counters[f"{exc.reason}_errors"] += 1
                self.port.refused(exc.code, f"bad frame: {exc}", frame=frame)
            else:
                if len(self._decoded) >= CACHE_LIMIT:
                    self._decoded.clear()
                self._decoded[frame] = cmd
        if cmd is not None:
            counters["frames_good"] += 1
        if self.wait is not None:
            self._hold(cmd, now)
        elif cmd is None:
            self._emit(Response.error(ErrorCode.INVALID_COMMAND))
        elif isinstance(cmd, WaitMoved):
            self._take_up(cmd, now)
        else:
            self._emit(self._execute(cmd))

    def _execute(self, cmd: Command) -> Response:
        """Run a command; a failure the dispatcher did not turn into an error code (a bug)
        is logged and answered E4, so the link never dies of one command."""
        try:
            return self.port.handle(cmd)
        except Exception:
            return self._failed(cmd)

    def _failed(self, cmd: Command) -> Response:
        """The answer to a command whose execution raised (called in its except block)."""
        self.counters["internal_errors"] += 1
        log.exception("%r failed", cmd)
        self.port.refused(ErrorCode.MOTOR_ERROR, "internal error (a bug: see the log)", cmd)
        return Response.error(ErrorCode.MOTOR_ERROR)

    def _hold(self, cmd: Command | None, now: float) -> None:
        if isinstance(cmd, StopMove):
            self.counters["stops_while_held"] += 1
            self._held.append(self._encode(self._execute(cmd)))
            self.poll(now)  # the stop may have ended the wait
            return
        if self._held_places >= self.held_limit:
            self.counters["held_overflow"] += 1
            # No place left: E0, or E1 for a frame that failed its checks (E1 comes first).
            code = ErrorCode.FULL_BUFFER if cmd is not None else ErrorCode.INVALID_COMMAND
            if cmd is not None:
                why = f"held-frame buffer full ({self.held_limit} frames behind a WaitMoved)"
                self.port.refused(code, why, cmd)
            self._held.append(self._encode(Response.error(code)))
        else:
            self._held.append(cmd)
            self._held_places += 1
        if len(self._held) > self.counters["held_max"]:
            self.counters["held_max"] = len(self._held)

    def _take_up(self, cmd: WaitMoved, now: float) -> None:
        self.counters["waits_taken_up"] += 1
        result = self.port.wait_begin(cmd, now)
        if isinstance(result, Wait):
            self.wait = result
            # The motor may have stopped between the check and now, when no wait was there
            # to be woken: look once more.
            self.poll(now)
        else:
            self._emit(result)

    def _release(self, now: float) -> None:
        """The WaitMoved was answered: run the kept frames in order until another holds."""
        held = self._held
        while held and self.wait is None:
            item = held.popleft()
            if isinstance(item, bytes):
                self._emit_encoded(item)
                continue
            self._held_places -= 1
            if item is None:
                self._emit(Response.error(ErrorCode.INVALID_COMMAND))
            elif isinstance(item, WaitMoved):
                self._take_up(item, now)
            else:
                self._emit(self._execute(item))

    # -- responses --------------------------------------------------------------------------
    def _encode(self, resp: Response) -> bytes:
        key = (resp.ack, resp.payload)  # hashed in C, unlike the dataclass
        data = self._encoded.get(key)
        if data is None:
            data = encode_response(resp, self.options)
            if len(self._encoded) >= CACHE_LIMIT:
                self._encoded.clear()
            self._encoded[key] = data
        return data

    def _emit(self, resp: Response) -> None:
        self._emit_encoded(self._encode(resp))

    def _emit_encoded(self, data: bytes) -> None:
        self._out += data
        self._count_answer(data)

    def _count_answer(self, data: bytes) -> None:
        """An answer emitted: counted, and kept among the last answers."""
        counters = self.counters
        counters["responses"] += 1
        self._answer_no += 1
        self._answers_seen.append((self._answer_no, data))
        if data[0] == 0x00:
            counters[_SENT[data[1]]] += 1
