"""The link thread's CPU time by part (daemon/link/cpu_parts.py): every part of a round trip
gets the time between its marks, on an injected clock; off, the session talks to the
dispatcher itself; the environment switch is strict."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from motorctl.daemon.errors import StartupError
from motorctl.daemon.link.cpu_parts import PARTS, CpuParts, TimedPort
from motorctl.daemon.start.link_parts import CPU_PARTS_ENV, cpu_parts
from motorctl.protocol.codec import IsReady
from tests.support.frames import frame
from tests.support.inprocess import LiveDaemon


def test_each_mark_gives_the_time_since_the_last_to_its_part() -> None:
    ticks = iter([100, 130, 180, 181])
    parts = CpuParts(clock=lambda: next(ticks))
    parts.mark("read")
    parts.mark("decode")
    parts.mark("read")
    assert parts.summary() == {
        "ns": {**dict.fromkeys(PARTS, 0), "read": 31, "decode": 50},
        "commands": 0,
    }


def test_a_round_trip_goes_through_every_part(tmp_path: Path) -> None:
    """A real PTY and the daemon's dispatcher: one IsReady marks each part once (a clock
    that moves 1 ns a reading: each part gets exactly the readings between its marks)."""
    clock = itertools.count(0)
    parts = CpuParts(clock=lambda: next(clock))
    served = LiveDaemon(tmp_path, parts=parts)
    try:
        assert isinstance(served.link.session.port, TimedPort)
        host = served.host()
        host.write(frame(IsReady(0)))
        assert [r.as_bool for r in host.responses(1)] == [True]
        served.stop()
        host.close()
        summary = parts.summary()
        assert summary["commands"] == 1
        ns = summary["ns"]
        assert isinstance(ns, dict)
        assert set(ns) == set(PARTS)
        # read, decode, dispatch, encode, write once; the poll once per turn at least
        assert all(ns[part] == 1 for part in ("read", "decode", "dispatch", "encode", "write"))
        assert ns["poll"] >= 1 and ns["bookkeeping"] >= 1
        assert served.link.status()["cpu_parts"] == parts.summary()
    finally:
        served.close()


def test_off_the_session_has_the_dispatcher_itself(tmp_path: Path) -> None:
    served = LiveDaemon(tmp_path)
    try:
        assert served.link.parts is None
        assert served.link.session.port is served.daemon.dispatcher
        assert "cpu_parts" not in served.link.status()
    finally:
        served.close()


@pytest.mark.parametrize(("value", "on"), [("1", True), ("0", False), ("", False)])
def test_the_environment_asks_for_it(monkeypatch: pytest.MonkeyPatch, value: str, on: bool) -> None:
    monkeypatch.setenv(CPU_PARTS_ENV, value)
    assert (cpu_parts() is not None) is on


def test_another_value_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CPU_PARTS_ENV, "yes")
    with pytest.raises(StartupError, match="MOTORCTL_LINK_CPU_PARTS='yes'"):
        cpu_parts()
