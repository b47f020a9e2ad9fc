"""The error reasons and journal lines the pages quote are the daemon's own words.

docs/protocol.md ("Why an error"), docs/status.md (the ``errors`` row's ``reason``) and
docs/service.md ("Error answers") quote reasons and a journal line; each is produced here,
by the link session in front of a daemon on a virtual clock (SessionRig) whose machine is the
README's (3 motors, end stops at +-10000, pins 4..7 inputs) with soft limits on motor 0 and no
DC motor, and each quote must be one of them. (The client's own messages the README quotes:
tests/client/test_cli_e2e.py; the walkthrough: test_readme.py.)"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator

import pytest

from motorctl.protocol.codec import (
    Command,
    DcMove,
    ErrorCode,
    IsReady,
    Move,
    MoveTo,
    SetPin,
    WaitMoved,
)
from tests.support import REPO
from tests.support.sessions import SessionRig

E = ErrorCode

CONFIG = """
[[motors]]
name = "x"
soft_limit_min = -9000
soft_limit_max = 9000
[[motors]]
name = "y"
[[motors]]
name = "z"
""" + "".join(
    f'[[pins]]\nnumber = {n}\nmode = "{"input" if n >= 4 else "output"}"\n' for n in range(8)
)


def one_line(text: str) -> str:
    return " ".join(text.split())


def quotes(text: str) -> list[str]:
    """The code spans of ``text``, each on one line."""
    return [one_line(q) for q in re.findall(r"`([^`]+)`", text, re.S)]


def section(page: str, start: str, end: str) -> str:
    text = (REPO / "docs" / page).read_text(encoding="utf-8")
    return text.split(start, 1)[1].split(end, 1)[0]


class Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@pytest.fixture(scope="module")
def produced(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[set[str], list[str]]]:
    """The reasons of the pages' examples, as the daemon decides them; its journal lines."""
    journal = Lines()
    logger = logging.getLogger("motorctl.errors")
    logger.addHandler(journal)
    level = logger.level
    logger.setLevel(logging.INFO)
    try:
        yield examples(SessionRig(tmp_path_factory.mktemp("errors"), CONFIG)), journal.lines
    finally:
        logger.removeHandler(journal)
        logger.setLevel(level)


def examples(w: SessionRig) -> set[str]:
    reasons = w.daemon.dispatcher.refusals

    def reason(data: bytes | Command) -> str:
        got = w.ask(data) if isinstance(data, bytes) else [w.call(data)]
        assert got[-1].error_code is not None, data
        last = reasons.status()["last"]
        assert last is not None
        return str(last["reason"])

    out = {
        reason(MoveTo(5, True, 0, 0, 0, 0)),
        reason(DcMove(True, 100, False)),
        reason(MoveTo(0, True, 30000, 0, 0, 0)),
        reason(SetPin(5, True)),
        reason(bytes.fromhex("03 00 00 00 00 00 00 00 00 00")),
    }
    w.motors[2].position_lost = True
    out.add(reason(MoveTo(2, True, 0, 0, 0, 0)))
    assert w.call(Move(1, True, 3, 0, 0)).ack
    w.send(WaitMoved(1, 60000))
    assert [r.error_code for r in w.quiet_until_answered(15.0)] == [E.MOTOR_ERROR]
    out.add(str(reasons.status()["last"]["reason"]))
    assert reason(IsReady(1)).startswith("end stop hit")
    return out


def test_the_reasons_docs_protocol_quotes(produced: tuple[set[str], list[str]]) -> None:
    quoted = quotes(section("protocol.md", "### Why an error", ", with the commands"))
    assert len(quoted) >= 7  # the section was found
    assert [q for q in quoted if q not in produced[0]] == []


def test_the_reasons_docs_status_quotes(produced: tuple[set[str], list[str]]) -> None:
    row = section("status.md", "| `errors` |", "\n")
    quoted = quotes(row.split("`reason` (", 1)[1].split("), `fix`", 1)[0])
    assert len(quoted) >= 4
    assert [q for q in quoted if q not in produced[0]] == []


def test_the_journal_line_docs_service_quotes(produced: tuple[set[str], list[str]]) -> None:
    text = section("service.md", "**Error answers.**", "\n\n")
    (line,) = [q for q in quotes(text) if q.startswith("motor ")]
    assert line in produced[1]
