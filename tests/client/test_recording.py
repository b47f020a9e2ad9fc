"""Reading trace files (client/recording.py), made up or recorded by the daemon's recorder:
rotated parts (one missing, one given twice, files that overlap), merged files read link by
link, a file of foreign link types only. No process, no clock."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from motorctl.client.conversation import EXTRA, analyse
from motorctl.client.recording import TraceFileError, load
from motorctl.client.trace import one_link
from motorctl.daemon.link.recorder import rotated
from motorctl.protocol.capture.format import CaptureInfo, Record
from motorctl.protocol.capture.writer import encode
from motorctl.protocol.codec import IsReady, Response
from tests.support.traces import IN, INFO, MS, OUT, ans, cmd, conversation, merged, rotating


def test_a_missing_part_is_named_and_a_complete_set_reads_clean(tmp_path: Path) -> None:
    rec, path = rotating(tmp_path, files=100)
    parts = sorted(tmp_path.iterdir())
    assert rec.part == len(parts) > 3
    whole = load(parts)
    assert whole.problems == [] and len(whole.records) == 80
    assert analyse(whole.records, INFO).unanswered == []
    rotated(path, 1).unlink()  # the part before the newest: a hole
    holed = load(sorted(tmp_path.iterdir()))
    (note,) = holed.problems
    assert f"session {rec.session}" in note and f"lacks part {rec.part - 1}" in note
    newest = load([path])  # one part alone: its session's start is missing
    assert any("start of session" in p for p in newest.problems)


def test_a_part_given_twice_is_left_out_and_files_that_overlap_are_refused(
    tmp_path: Path,
) -> None:
    _, path = rotating(tmp_path, files=100)
    parts = sorted(tmp_path.iterdir())
    copy = tmp_path / "copy.pcapng"
    copy.write_bytes(path.read_bytes())
    twice = load([path, copy])
    assert any("was given already" in p for p in twice.problems)
    other = tmp_path / "other.pcapng"  # a second recording of the same time: not a part
    other.write_bytes(
        encode(
            CaptureInfo(session="bbbb", part=1),
            [Record(5 * MS, IN, cmd(IsReady(0))), Record(390 * MS, OUT, ans(Response.ok()))],
        )
    )
    with pytest.raises(TraceFileError, match="overlap in time"):
        load([*parts, other])


def test_a_merged_file_decodes_each_interface_as_its_own_link(tmp_path: Path) -> None:
    device = CaptureInfo(role="daemon", port="/dev/ttyAMA0", session="d", part=1)
    tap = CaptureInfo(role="tap", port="host A <-> device B", frame_gap_ms=20, session="t", part=1)
    talk = conversation()[:4]
    later = [Record(r.ts_ns + 50_000, r.direction, r.data) for r in talk]  # the tap, a bit later
    path = tmp_path / "merged.pcapng"
    path.write_bytes(merged((device, talk), (tap, later)))
    both = load([path])
    assert [link.interface for link in both.links] == [0, 1]
    assert [link.info.role for link in both.links if link.info] == ["daemon", "tap"]
    assert both.links[1].info is not None and both.links[1].info.frame_gap_ms == 20
    for link in both.links:  # each link pairs its own answers: nothing twice, nothing extra
        conv = analyse(link.records, link.info or INFO)
        assert len(conv.frames) == 2 and conv.unanswered == []
        assert not [r for r in conv.rows if r.kind == EXTRA]
    assert (
        both.describe_interfaces()
    ) == "0: /dev/ttyAMA0 (daemon, 4 runs), 1: host A <-> device B (tap, 4 runs)"
    one = load([path], interface=1)
    assert [link.interface for link in one.links] == [1]
    assert [(r.ts_ns, r.data, r.interface) for r in one.records] == [
        (r.ts_ns, r.data, 1) for r in later
    ]
    with pytest.raises(TraceFileError, match="pass --interface N"):
        one_link([path], None, None, None)  # the replay's reader: one link or none
    with pytest.raises(TraceFileError, match="no motorctl interface 7"):
        load([path], interface=7)


def test_a_file_of_foreign_link_types_only_is_refused_by_name(tmp_path: Path) -> None:
    ether = bytearray(encode(INFO, conversation()[:2]))
    shb_len = struct.unpack_from("<I", ether, 4)[0]
    struct.pack_into("<H", ether, shb_len + 8, 1)  # the interface: Ethernet
    path = tmp_path / "ether.pcapng"
    path.write_bytes(bytes(ether))
    with pytest.raises(TraceFileError, match=rf"link type 1 \(Ethernet\).*offset {shb_len}"):
        load([path])
