"""The replay's plan (client/replay.py) of a made-up recording: each run waits for the
answers it waited for, and pauses inside a frame are kept. No process, no clock. The replay
against daemons: tests/client/test_replay_e2e.py, tests/client/test_trace_e2e.py."""

from __future__ import annotations

import pytest

from motorctl.client.replay import plan
from tests.support.traces import INFO, conversation


def test_plan_waits_for_answers_and_keeps_framing_pauses() -> None:
    sends = plan(conversation(), INFO)
    assert [s.need for s in sends] == [0, 1, 2, 2, 3, 3, 4]
    assert sends[3].at_s == pytest.approx(0.030)
    assert [s.framing for s in sends] == [False, False, False, True, False, True, False]
