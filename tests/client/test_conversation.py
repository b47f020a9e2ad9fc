"""The analysis of a recorded conversation (client/conversation.py) on made-up byte runs:
frames cut as the daemon cuts them, answers paired in order. No process, no clock."""

from __future__ import annotations

from motorctl.client.conversation import BAD_FRAME, EXTRA, GAP, analyse
from motorctl.protocol.capture.format import Record
from motorctl.protocol.codec import IsReady
from tests.support.traces import IN, INFO, MS, cmd, conversation


def test_analysis_frames_as_the_daemon_does_and_pairs_answers_in_order() -> None:
    conv = analyse(conversation(), INFO)
    kinds = [r.kind for r in conv.rows]
    assert kinds.count(GAP) == 1 and kinds.count(BAD_FRAME) == 1 and kinds.count(EXTRA) == 1
    assert len(conv.frames) == 5
    assert [f.answer.text if f.answer else None for f in conv.frames] == [
        "#1 ready",
        "#2 ok",
        "#3 pos=100",
        "#4 pos=200",
        "#5 E1 Invalid Command",
    ]
    assert conv.frames[3].answer is not None and conv.frames[3].answer.rtt_ns == 1 * MS
    assert conv.frames[3].t_ns == 133 * MS  # its last byte's run


def test_no_gap_when_silence_is_exactly_the_frame_gap() -> None:
    records = [Record(0, IN, b"\x03\x00"), Record(10 * MS, IN, cmd(IsReady(0))[2:])]
    conv = analyse(records, INFO)
    assert [r.kind for r in conv.rows] == ["command"]
