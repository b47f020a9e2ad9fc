"""hwtest/dspin_chain.py (the program behind spi-sim.c's user bus in the hardware tier) and
hwtest/test_dspin_daemon.py's transcript decoding, here without a guest: the responder fed
transfers as spi-sim.c's header frames them, and the decoding of what it recorded."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hwtest.dspin_chain import HEADER, Responder
from hwtest.test_dspin_daemon import check_transcript, per_chip
from motorctl.hal.dspin.chips import L6480
from motorctl.hal.dspin.commands import Command, Op, go_to_dir, simple
from motorctl.hal.layers.dspin.chain import frame


def answer(r: Responder, tx: bytes, mode: int = 3, seq: int = 1) -> bytes:
    return r.answer(HEADER.pack(seq, len(tx), 1_000_000, mode, 8, 1), tx)


def exchange(r: Responder, sequences: dict[int, bytes]) -> None:
    for tx in frame(3, sequences):
        answer(r, tx, seq=len(r.transcript) + 1)


def test_a_goto_and_a_fault_decoded_per_chip(tmp_path: Path) -> None:
    control = tmp_path / "control.json"
    r = Responder(control, switch_at=-400)
    status = simple(Op.GET_STATUS).encode()
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))  # clears the power-up UVLO
    exchange(r, {0: go_to_dir(1, 320).encode()})
    control.write_text('{"1": ["OCD"]}')
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))
    x, y, _ = (per_chip(r.transcript, i) for i in range(3))
    assert [s.command for s in x] == [
        Command(Op.GET_STATUS),
        Command(Op.GO_TO_DIR, dir=1, value=320),
        Command(Op.GET_STATUS),
    ]
    assert [s.command.op for s in y][-1] is Op.GET_STATUS
    word = int.from_bytes(y[-1].answer, "big")
    assert "OCD" in L6480.status.decode(word).faults
    assert x[1].seq == (4, 5, 6, 7)
    assert [s.command.op for s in y] == [Op.GET_STATUS, *[Op.NOP] * 4, Op.GET_STATUS]


def test_a_transfer_in_another_mode_is_recorded_as_refused(tmp_path: Path) -> None:
    r = Responder(tmp_path / "control.json", switch_at=-400)
    assert answer(r, bytes([0xD0, 0xD0, 0xD0]), mode=0) == bytes(3)
    record: dict[str, Any] = r.transcript[-1]
    assert record["error"] and "mode 0" in record["error"]
    with pytest.raises(AssertionError):
        check_transcript(r.transcript)
