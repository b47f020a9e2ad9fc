"""``motorctl trace --json``'s rows (client/trace.py): every row carries the typed fields
docs/trace.md lists. On made-up byte runs; the command on real recordings:
tests/client/test_trace_files.py."""

from __future__ import annotations

import re

from motorctl.client.conversation import analyse
from motorctl.client.trace import FIELDS, row_json
from motorctl.protocol.capture.format import Record
from motorctl.protocol.codec import DcMove, ErrorCode, GetAbsPos, GetPin, MoveTo, Response
from tests.support import REPO
from tests.support.traces import IN, INFO, MS, OUT, ans, cmd


def test_rows_carry_typed_fields() -> None:
    records = [
        Record(0, IN, cmd(MoveTo(1, False, -300, 250, 3, 4))),
        Record(1 * MS, OUT, ans(Response.ok())),
        Record(2 * MS, IN, cmd(GetAbsPos(1))),
        Record(3 * MS, OUT, ans(Response.position(-300))),
        Record(4 * MS, IN, cmd(DcMove(False, 50, True))),
        Record(5 * MS, OUT, ans(Response.error(ErrorCode.MOTOR_NOT_READY))),
        Record(6 * MS, IN, cmd(GetPin(5))),
        Record(7 * MS, OUT, ans(Response.boolean(True))),
    ]
    rows = [row_json(r, 0) for r in analyse(records, INFO).rows]
    assert all(set(FIELDS) <= set(r) for r in rows)
    move, moved, read, pos, dc, e3, pin, high = rows
    assert (move["command"], move["code"], move["motor"], move["direction"]) == (
        "MoveTo",
        1,
        1,
        "down",
    )
    assert (move["position"], move["speed"], move["acc"], move["dec"]) == (-300, 250, 3, 4)
    assert moved["command"] == "MoveTo" and moved["ack"] is True and moved["position"] is None
    assert moved["rtt_us"] == 1000.0 and moved["packet"] == 0 and moved["interface"] == 0
    assert (pos["command"], pos["motor"], pos["position"]) == ("GetAbsPos", 1, -300)
    assert read["position"] is None
    assert (dc["direction"], dc["time_ms"], dc["hiz"], dc["motor"]) == ("reverse", 50, True, None)
    assert dc["text"] == "#3 DcMove(dir=reverse, time_ms=50, hiz=true)"
    assert (e3["ack"], e3["error_code"], e3["error_name"], e3["error"]) == (
        False,
        0xE3,
        "Motor not ready",
        "E3",
    )
    assert (pin["pin"], high["pin"], high["value"]) == (5, 5, 1)


def test_the_docs_list_every_key_of_a_row() -> None:
    """docs/trace.md's table of a row's keys names each of :data:`FIELDS` (the command
    table's fields among them)."""
    text = (REPO / "docs" / "trace.md").read_text(encoding="utf-8")
    section = text[text.index("Every row has every key below") : text.index("## Wireshark")]
    keys = {
        key
        for line in section.splitlines()
        if line.startswith("| `")
        for key in re.findall(r"`(\w+)`", line.split("|")[1])
    }
    assert set(FIELDS) <= keys, set(FIELDS) - keys
    assert {"ready", "waypoint", "hiz", "timeout_ms"} <= set(FIELDS)
