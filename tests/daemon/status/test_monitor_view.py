"""The live monitor's view drawn from known documents into a string (rich's recording
console): what a user reads for a known state, with and without the per-motor timing
figures of issue 15; frames/s; the message when rich is missing; the view marked stale once
the daemon is gone, a full daemon told from an absent one, --once off a terminal unwrapped
(against a status socket in this process). Against a live daemon:
tests/daemon/status/test_document_e2e.py."""

from __future__ import annotations

import io
import queue
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from motorctl.daemon.status.monitor import Ending
from motorctl.daemon.status.monitor_view import (
    Seen,
    _follow,
    frames_per_second,
    once,
    render,
    watch,
)
from motorctl.daemon.status.reader import subscribe
from motorctl.daemon.status.server import MAX_SUBSCRIBERS, StatusServer
from tests.daemon.status.test_metrics import DOC
from tests.support import REPO
from tests.support.wait import until


def drawn(doc: dict[str, Any], width: int = 140, **kw: Any) -> str:
    console = Console(width=width, record=True, file=io.StringIO(), color_system=None)
    console.print(render(doc, **kw))
    return console.export_text()


def test_a_known_state_drawn() -> None:
    doc = {
        **DOC,
        "link": {
            **DOC["link"],
            "recent": [
                {
                    "at_s": 4.0,
                    "frame": "01 09 01 00 00 03 00 00 00 17",
                    "command": "MoveTo(motor=9, dir=up, pos=3, speed=0, acc=0, dec=0)",
                    "answer": "00 e2 00 00 a1",
                    "result": "E2 Invalid Address",
                },
                {
                    "at_s": 4.5,
                    "frame": "03 00 00 00 00 00 00 00 00 8b",
                    "command": "IsReady(motor=0)",
                    "answer": None,
                    "result": None,
                },
            ],
        },
    }
    text = drawn(doc, rate=12.5, since_s=0.25, note="updated 0.2 s ago")
    lines = text.splitlines()
    assert "motorctld  up 0:01:40  executor process, compiled core (pid 12) alive" in text
    assert "STATE NOT SAVED" in text
    row0 = next(line for line in lines if 'we"ird\\name' in line and "fault" in line)
    assert row0.split()[:7] == ["0", 'we"ird\\name', "fault", "-12", "-250", "1", "2"]
    assert "step timing lost (position lost: home it)" in row0
    assert next(line for line in lines if line.split()[:3] == ["1", "y", "idle"])
    # issue 15's figures: absorbed, slid, worst late, worst lag, its limit, microsteps,
    # lag faults, faults by cause
    timing = next(line for line in lines if line.split()[:2] == ["0", "40"])
    assert timing.split()[2:] == [
        "12.5",
        "850",
        "1.25",
        "2.00",
        "16",
        "2",
        "endstop",
        "1,",
        "timing_lost",
        "2",
    ]
    assert "step edges 1,000  lateness p50 7 p99 31 p99.9 63 max 90 us  late (>100 us) 3" in text
    assert "timing lost 2" in text and "segments discarded 0" in text
    assert "pins 3:out H  4:in ?" in text
    assert "DC motor forward, 0.2 s left" in text
    assert "frames 10 (12.5/s)  bad frames checksum 1  errors sent E2x4" in text
    newest, older = (line for line in lines if "motor=" in line)
    assert newest.split()[:2] == ["0.8", "03"] and newest.rstrip().endswith("(owed)")
    assert older.split()[0] == "1.2" and older.rstrip().endswith("E2 Invalid Address")
    assert "TMC5160 /dev/spidev0.0: polls 7" in text and "faults ot 1" in text
    assert [line for line in lines if line.strip()][-1].strip() == "updated 0.2 s ago"


def test_a_daemon_without_timing_figures_and_an_empty_document() -> None:
    plain = {k: v for k, v in DOC.items() if k not in ("drivers", "dc", "pins")}
    plain["motors"] = [
        {k: v for k, v in m.items() if k not in ("timing", "faults")} for m in DOC["motors"]
    ]
    text = drawn(plain)
    assert "step timing per motor" not in text and "motors" in text
    assert "pins not reported" in text and "DC motor not reported" in text
    assert "frames 10  bad frames" in text and "/s)" not in text  # no rate: none shown
    empty = drawn({})
    assert "motorctld  up ?" in empty and "link not serving" in empty


def test_frames_per_second() -> None:
    def seen(frames: int, t: float, at: float) -> Seen:
        return Seen({"monotonic_s": t, "link": {"counters": {"frames": frames}}}, at)

    a, b = seen(100, 10.0, 50.0), seen(150, 12.0, 52.0)
    assert frames_per_second(b, None, 52.0, 0.25) is None
    assert frames_per_second(b, a, 52.1, 0.25) == 25.0
    # no update for longer than a period and a half: nothing changed, so no frames came
    assert frames_per_second(b, a, 52.0 + 1.5 * 0.25 + 0.6, 0.25) == 0.0


def test_without_rich_the_monitor_says_what_to_install(tmp_path: Path) -> None:
    """The daemon never needs rich; the monitor, without it, names the packages and exits 1
    (no traceback), both as motorctld --status --watch and as motorctl monitor."""
    for call in (
        "from motorctl.daemon.start.main import main; "
        f"sys.exit(main(['--status', '--watch', '--state-dir', '{tmp_path}']))",
        "from motorctl.client.cli import main; "
        f"sys.exit(main(['monitor', '--state-dir', '{tmp_path}']))",
    ):
        out = subprocess.run(
            [sys.executable, "-c", "import sys; sys.modules['rich'] = None; " + call],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=REPO,
        )
        assert out.returncode == 1, out.stderr
        assert "apt install python3-rich" in out.stderr and "motorctl[monitor]" in out.stderr
        assert "Traceback" not in out.stderr


def test_the_trace_when_the_daemon_records_one() -> None:
    trace = {
        "file": "/run/motorctl/link.pcapng",
        "runs": 1234,
        "dropped_runs": 0,
        "bytes_written": 56789,
        "rotations": 2,
        "write_errors": 1,
        "lost_bytes": 300,
        "session": "3f2a9c01d4e5",
        "part": 3,
    }
    text = drawn({**DOC, "trace": trace}, width=250)
    assert (
        "trace /run/motorctl/link.pcapng (part 3 of session 3f2a9c01d4e5)  runs 1,234  written "
        "56,789 bytes  runs left out 0  write errors 1  bytes lost 300"
    ) in text
    untraced = {key: value for key, value in DOC.items() if key != "trace"}
    assert "trace " not in drawn(untraced)


def test_a_stale_view_is_marked_as_such_throughout() -> None:
    text = drawn(DOC, rate=12.5, since_s=12.0, stale="motorctld at /run/x stopped")
    lines = [line for line in text.splitlines() if line.strip()]
    assert lines[0].startswith("NOT LIVE: motorctld at /run/x stopped. Everything below is")
    assert "12.0 s ago" in lines[0]
    assert (
        "motorctld (last seen)  up 0:01:40 then  executor process, compiled core (pid 12) state "
        "unknown"
    ) in text
    assert " alive" not in text and "frames 10  bad" in text  # no rate read as live


def test_once_off_a_terminal_keeps_each_line_whole(
    doc_server: StatusServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    out = io.StringIO()
    monkeypatch.setattr(sys, "stdout", out)
    assert once(doc_server.path) == 0
    text = out.getvalue()
    assert max(map(len, text.splitlines())) > 100  # not wrapped at rich's 80 columns
    assert "link host port open  frames 10  bad frames checksum 1  errors sent E2x4" in text


def test_watch_marks_the_whole_view_stale_once_the_daemon_is_gone(doc_server: StatusServer) -> None:
    out = io.StringIO()
    console = Console(file=out, width=200, color_system=None)
    ending = Ending()
    thread = threading.Thread(
        target=watch, args=(doc_server.path, 50, console, ending), daemon=True
    )
    thread.start()
    try:
        until(
            "the first drawing",
            lambda: "executor process, compiled core (pid 12) alive" in out.getvalue(),
        )
        doc_server.close()
        until("the stale drawing", lambda: "NOT LIVE" in out.getvalue())
    finally:
        ending.request()
        thread.join(10)
    assert not thread.is_alive()
    stale = out.getvalue().split("NOT LIVE", 1)[1]
    assert stale.startswith(f": motorctld at {doc_server.path} stopped. Everything below")
    assert "(last seen)" in stale and "state unknown" in stale and " alive" not in stale
    assert "retrying every 1 s" in stale


def test_a_full_daemon_is_not_called_absent(doc_server: StatusServer) -> None:
    streams = [subscribe(doc_server.path, period_s=0.02) for _ in range(MAX_SUBSCRIBERS)]
    for stream in streams:
        next(stream)  # each reads its update: none can be evicted
    updates: queue.Queue[Seen | str] = queue.Queue()
    stop = threading.Event()
    thread = threading.Thread(target=_follow, args=(doc_server.path, 0.02, updates, stop))
    thread.start()
    try:
        note = updates.get(timeout=30)
    finally:
        stop.set()
        thread.join(10)
        for stream in streams:
            stream.close()
    assert isinstance(note, str) and "no motorctld" not in note
    assert note.startswith(
        f"motorctld at {doc_server.path} is running but refused the subscription"
    )
    assert "too many subscribers (8)" in note and "the daemon is full" in note
