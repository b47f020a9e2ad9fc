"""The daemon's trace recorder (daemon/link/recorder.py): it rotates within its bounds and
keeps the newest runs, its memory is bounded and a loss is written into the file. Called
as the link thread calls it, its writer's flush by hand: no thread, no clock."""

from __future__ import annotations

from pathlib import Path

from motorctl.client.conversation import LOST, analyse
from motorctl.client.recording import load
from motorctl.daemon.link.recorder import TraceRecorder, rotated
from motorctl.protocol.capture.reader import parse
from tests.support.traces import INFO


def test_recorder_rotates_within_its_bounds_and_keeps_the_newest(tmp_path: Path) -> None:
    path = tmp_path / "t.pcapng"
    rec = TraceRecorder(
        path, INFO, max_bytes=2000, files=3, clock_origin=0.0, wall_origin_ns=0, flush_s=3600
    )
    rec.open()
    for i in range(200):
        rec.received(bytes([i % 256]) * 10, i / 1000)
        rec.sent(bytes([i % 256]) * 5, i / 1000 + 0.0001)
        if i % 20 == 19:
            rec._flush()  # what the writer thread does every flush_s
    rec.close()
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == ["t.pcapng", "t.pcapng.1", "t.pcapng.2"]
    assert all(f.stat().st_size <= 2000 for f in files)
    assert rec.rotations > 2 and rec.dropped_runs == 0
    cap = load([rotated(path, 2), path, rotated(path, 1)])  # any order
    times = [r.ts_ns for r in cap.records]
    assert times == sorted(times)
    # the parts are numbered: the first ones were rotated away, and the reader says so
    (note,) = cap.problems
    assert f"the start of session {rec.session}" in note and "is missing" in note
    assert cap.links[0].sessions == {rec.session: [rec.part - 2, rec.part - 1, rec.part]}
    # the newest runs are all there, up to the last one, without a hole
    assert times[-1] == round(0.199 * 1e9 + 0.0001 * 1e9)
    expected = sorted(
        [round(i / 1000 * 1e9) for i in range(200)]
        + [round((i / 1000 + 0.0001) * 1e9) for i in range(200)]
    )
    assert times == expected[-len(times) :]


def test_recorder_memory_is_bounded_and_the_loss_is_written_down(tmp_path: Path) -> None:
    path = tmp_path / "t.pcapng"
    rec = TraceRecorder(
        path,
        INFO,
        max_bytes=1 << 20,
        files=1,
        clock_origin=0.0,
        wall_origin_ns=0,
        flush_s=3600,
        buffer_limit=500,
    )
    rec.open()
    for i in range(50):  # the writer never runs: the buffer fills
        rec.received(bytes(10), i / 1000)
    rec._flush()
    rec.received(b"\x03" * 10, 1.0)
    rec.close()
    cap = parse(path.read_bytes())
    assert rec.dropped_runs == 50 - len(cap.records) + 1 > 0
    assert cap.records[-1].dropped == rec.dropped_runs
    conv = analyse(cap.records, INFO)
    assert any(r.kind == LOST for r in conv.rows)
