"""The replay's plan (client/replay.py) of a made-up recording: each run waits for the
answers it waited for, and pauses inside a frame are kept. No process, no clock. The replay
against daemons: tests/client/test_replay_e2e.py, tests/client/test_trace_e2e.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.client import cli
from motorctl.client.replay import plan
from tests.support.traces import INFO, conversation, rotating


def test_plan_waits_for_answers_and_keeps_framing_pauses() -> None:
    sends = plan(conversation(), INFO)
    assert [s.need for s in sends] == [0, 1, 2, 2, 3, 3, 4]
    assert sends[3].at_s == pytest.approx(0.030)
    assert [s.framing for s in sends] == [False, False, False, True, False, True, False]


def test_a_replay_port_that_is_no_serial_device_is_said_as_motorctl_says_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file, a folder or nothing at --port: motorctl's one line (client/port_errors.py),
    not pyserial's "Could not configure port: (25, 'Inappropriate ioctl for device')"."""
    _, recording = rotating(tmp_path, 1)
    typo = tmp_path / "notes.txt"
    typo.write_text("")
    missing = tmp_path / "ttyNOPE"
    for port, says in (
        (typo, f"error: {typo}: not a serial device (a regular file)\n"),
        (tmp_path, f"error: {tmp_path}: not a serial device (a folder)\n"),
        (missing, f"error: cannot open {missing}: no such file (is motorctld running? "),
    ):
        assert cli.main(["replay", str(recording), "--port", str(port)]) == 2
        last = capsys.readouterr().err.splitlines(keepends=True)[-1]  # after the warnings
        assert last.startswith(says)
