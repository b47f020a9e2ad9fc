"""A recorded conversation, frame by frame (docs/trace.md): :func:`analyse` turns byte runs
(from the daemon's trace or the tap) into rows: each command frame with its decoded command
or its frame error, each answer decoded for the command it answers (error codes by name;
the one reading of an answer, :func:`motorctl.protocol.codec.decode_answer`)
with its round-trip time, partial frames the gap rule dropped, runs a writer left out.
Inbound runs are cut into frames as the daemon cuts them
(:class:`motorctl.protocol.framing.Framer`, with the recording's ``frame_gap_ms``; the
silence between two recorded runs stands for the silence the daemon watched); answers are
paired with frames in order, as the protocol answers them (every complete frame gets exactly
one answer, in arrival order). ``motorctl trace`` (client/trace.py) shows it; the replay
(client/replay.py) plays and judges it.

Pure computation; runs on the caller's thread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from motorctl.protocol.capture.format import CaptureInfo, Direction, Record
from motorctl.protocol.codec import (
    FRAME_LEN,
    RESPONSE_LEN,
    CodecOptions,
    Command,
    FrameError,
    Response,
    ResponseError,
    decode_command,
    decode_response,
    describe,
    describe_answer,
)
from motorctl.protocol.framing import Framer

COMMAND = "command"
BAD_FRAME = "bad_frame"
ANSWER = "answer"
BAD_ANSWER = "bad_answer"
EXTRA = "extra_answer"
GAP = "gap"
LOST = "lost"
PARTIAL = "partial"


@dataclass
class Row:
    """One line of the table: a frame, an answer or an event on the link."""

    t_ns: int
    direction: Direction
    kind: str
    data: bytes
    text: str
    frame: int | None = None  # the command frame's number (1 = first), for frames and answers
    command: Command | None = None
    response: Response | None = None
    error: str | None = None  # error code short name (answers) or frame error reason
    rtt_ns: int | None = None  # answers: from the last byte of the frame they answer
    run: int = -1  # the index of the run (record) it came from, in the records analysed
    packet: int = 0  # that run's packet number in its file (Wireshark's frame.number)
    interface: int = 0  # that run's interface


@dataclass
class Frame:
    """A complete command frame and what answered it."""

    number: int
    t_ns: int  # when its last byte was read
    data: bytes
    command: Command | None
    error: FrameError | None
    answer: Row | None = None


@dataclass
class Conversation:
    """A capture read back: its rows and frames, an incomplete frame or answer at the end,
    and how many runs of bytes were lost."""

    rows: list[Row] = field(default_factory=list)
    frames: list[Frame] = field(default_factory=list)
    partial_in: bytes = b""  # an incomplete frame at the end
    partial_out: bytes = b""  # an incomplete answer at the end
    lost_runs: int = 0

    @property
    def unanswered(self) -> list[Frame]:
        return [f for f in self.frames if f.answer is None]


def analyse(records: Sequence[Record], info: CaptureInfo) -> Conversation:
    """Frames, answers and events of a recording (one link's runs), in recorded order."""
    analysis = _Analysis(info)
    conv = analysis.conv
    for index, rec in enumerate(records):
        mark = len(conv.rows)
        analysis.step(rec)
        for row in conv.rows[mark:]:
            row.run, row.packet, row.interface = index, rec.packet, rec.interface
    conv.partial_in = bytes(analysis.pending)
    conv.partial_out = bytes(analysis.out_buf)
    return conv


class _Analysis:
    """The state :func:`analyse` carries from one run to the next."""

    def __init__(self, info: CaptureInfo) -> None:
        self.info = info
        self.opts = info.codec_options()
        self.framer = Framer(info.frame_gap_ms / 1000.0)
        self.conv = Conversation()
        self.pending = bytearray()  # what the framer holds, to show a dropped partial frame
        self.out_buf = bytearray()
        self.last_in: int | None = None
        self.waiting: list[Frame] = []  # frames not answered yet, in order
        self.next_answer = 0

    def step(self, rec: Record) -> None:
        conv = self.conv
        if rec.dropped:
            conv.lost_runs += rec.dropped
            conv.rows.append(
                Row(
                    rec.ts_ns,
                    rec.direction,
                    LOST,
                    b"",
                    f"{rec.dropped} byte runs left out here (the trace writer "
                    "fell behind): frames and answers may pair wrongly after "
                    "this",
                )
            )
        if rec.direction is Direction.TO_DEVICE:
            self._inbound(rec)
            return
        self.out_buf += rec.data
        while len(self.out_buf) >= RESPONSE_LEN:
            data = bytes(self.out_buf[:RESPONSE_LEN])
            del self.out_buf[:RESPONSE_LEN]
            target = None
            if self.next_answer < len(self.waiting):
                target = self.waiting[self.next_answer]
                self.next_answer += 1
            conv.rows.append(_answer(rec.ts_ns, data, target, self.opts))

    def _inbound(self, rec: Record) -> None:
        conv, framer, pending = self.conv, self.framer, self.pending
        if self.last_in is not None and framer.pending:
            silence = (rec.ts_ns - self.last_in) / 1e9
            if framer.idle(silence):
                conv.rows.append(
                    Row(
                        rec.ts_ns,
                        Direction.TO_DEVICE,
                        GAP,
                        bytes(pending),
                        f"partial frame dropped: {len(pending)} of {FRAME_LEN} bytes, then "
                        f"{silence * 1000:.1f} ms of silence (> frame_gap_ms "
                        f"{self.info.frame_gap_ms:g}); no answer",
                    )
                )
                pending.clear()
        self.last_in = rec.ts_ns
        frames = framer.feed(rec.data)
        pending += rec.data
        del pending[: len(frames) * FRAME_LEN]
        for data in frames:
            frame = _frame(len(conv.frames) + 1, rec.ts_ns, data, self.opts)
            conv.frames.append(frame)
            self.waiting.append(frame)
            if frame.command is not None:
                text = f"#{frame.number} {describe(frame.command)}"
                conv.rows.append(
                    Row(rec.ts_ns, rec.direction, COMMAND, data, text, frame.number, frame.command)
                )
            else:
                assert frame.error is not None
                conv.rows.append(
                    Row(
                        rec.ts_ns,
                        rec.direction,
                        BAD_FRAME,
                        data,
                        f"#{frame.number} frame error ({frame.error.reason}):"
                        f" {frame.error}; E1 expected",
                        frame.number,
                        error=frame.error.reason,
                    )
                )


def _frame(number: int, t_ns: int, data: bytes, opts: CodecOptions) -> Frame:
    try:
        return Frame(number, t_ns, data, decode_command(data, opts), None)
    except FrameError as exc:
        return Frame(number, t_ns, data, None, exc)


def _answer(t_ns: int, data: bytes, frame: Frame | None, opts: CodecOptions) -> Row:
    if frame is None:
        return Row(
            t_ns,
            Direction.TO_HOST,
            EXTRA,
            data,
            "answer with no frame to answer (the device sent more answers than it "
            "got complete frames)",
        )
    rtt = t_ns - frame.t_ns
    try:
        resp = decode_response(data, opts)
    except ResponseError as exc:
        row = Row(
            t_ns,
            Direction.TO_HOST,
            BAD_ANSWER,
            data,
            f"#{frame.number} bad answer: {exc}",
            frame.number,
            frame.command,
            rtt_ns=rtt,
        )
    else:
        code = resp.error_code
        row = Row(
            t_ns,
            Direction.TO_HOST,
            ANSWER,
            data,
            f"#{frame.number} {describe_answer(frame.command, resp)}",
            frame.number,
            frame.command,
            resp,
            code.short if code is not None else None,
            rtt,
        )
    frame.answer = row
    return row
