"""hwtest/dspin_chain.py (the program behind spi-sim.c's user bus in the hardware tier) and
hwtest/test_dspin_daemon.py's transcript decoding, here without a guest: the responder fed
transfers as spi-sim.c's header frames them, and the decoding of what it recorded."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import pytest

from hwtest.dspin_chain import HEADER, Responder, parse_lines
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


#: each chip's FLAG and BUSY on a line of its own, as hwtest/test_dspin_daemon.py wires them
WIRING = {
    "flag": [("gpiochip0", 17), ("gpiochip0", 22), ("gpiochip0", 5)],
    "busy": [("gpiochip0", 27), ("gpiochip0", 23), ("gpiochip0", 6)],
}


def test_flag_and_busy_drive_their_lines_low_while_the_chip_signals(tmp_path: Path) -> None:
    control = tmp_path / "control.json"
    driven: list[tuple[str, int, bool]] = []
    r = Responder(
        control, -400, WIRING, lambda chip, offset, high: driven.append((chip, offset, high))
    )
    # powered up: every FLAG low (UVLO latched), every BUSY high (nothing runs)
    assert sorted(driven) == sorted(
        [(c, o, False) for c, o in WIRING["flag"]] + [(c, o, True) for c, o in WIRING["busy"]]
    )
    status = simple(Op.GET_STATUS).encode()
    driven.clear()
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))  # the flags cleared: FLAG rises
    assert sorted(driven) == sorted((c, o, True) for c, o in WIRING["flag"])
    driven.clear()
    exchange(r, {0: go_to_dir(1, 320).encode()})  # x runs: its BUSY falls, nothing else
    assert driven == [("gpiochip0", 27, False)]
    assert [t["busy"] for t in r.transcript[-4:]] == [[0, 0, 0]] * 3 + [[1, 0, 0]]
    # a fault between transfers: the watcher's tick drives y's FLAG without one
    driven.clear()
    control.write_text('{"1": ["OCD"]}')
    n = len(r.transcript)
    r.tick()
    assert driven == [("gpiochip0", 22, False)] and len(r.transcript) == n
    r.tick()  # the same file: nothing again
    assert driven == [("gpiochip0", 22, False)]
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))
    assert r.transcript[-1]["flag"] == [0, 1, 0]  # OCD lasts: FLAG stays low


def test_chips_sharing_a_line_pull_it_low_while_any_of_them_signals(tmp_path: Path) -> None:
    control = tmp_path / "control.json"
    shared = ("gpiochip1", 3)
    levels: dict[tuple[str, int], bool] = {}
    wiring: dict[str, list[tuple[str, int] | None]] = {"flag": [shared, shared, None]}
    r = Responder(control, -400, wiring, lambda c, o, high: levels.__setitem__((c, o), high))
    assert levels == {shared: False}
    status = simple(Op.GET_STATUS).encode()
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))
    assert levels == {shared: True}
    control.write_text('{"0": ["TH_SD"]}')
    r.tick()
    assert levels == {shared: False}
    control.write_text('{"2": ["TH_SD"]}')  # on the unwired chip: the line goes up again
    os.utime(control, ns=(1, 1))  # (another mtime whatever the clock's resolution)
    r.tick()
    exchange(r, dict.fromkeys(range(3), status + bytes(2)))  # chip 0's latched TH_SD read
    assert levels == {shared: True}


@pytest.mark.parametrize("text", ["gpiochip0:17,-", "gpiochip0:17,GPIO22,-", "a:1,b:x,-"])
def test_a_line_list_that_is_not_one_line_per_chip_is_refused(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        parse_lines(text)
    assert parse_lines("gpiochip0:17,-,gpiochip1:0") == [("gpiochip0", 17), None, ("gpiochip1", 0)]
