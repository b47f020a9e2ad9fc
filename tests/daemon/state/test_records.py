"""The state files' format and strict reading (daemon/state/records.py), without a daemon:
the bad records listed, saved motors matched with configured ones, the bound on a file's
size. (What a daemon does with what is read: tests/daemon/state/test_persistence.py.)"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from motorctl.daemon.state import records as st
from motorctl.daemon.state.records import MotorIdentity, StateError, parse_state, read_state
from motorctl.protocol.codec import POS_MIN, WAYPOINTS


def test_parse_state_lists_the_bad_records() -> None:
    state = parse_state(b'{"version": 2, "motors": [3, {"name": "z"}]}')
    assert state.motors == [] and state.slots == {}
    assert [(b.index, b.name) for b in state.bad] == [(0, None), (1, "z")]
    assert state.bad[0].problem == "motors[0] is not an object"
    assert state.bad[1].problem == "motors[1].waypoints is not a list"


def test_match_motors_unit() -> None:
    state = parse_state(
        json.dumps(
            {
                "version": 2,
                "motors": [
                    {
                        "name": "a",
                        "fingerprint": "f",
                        "position": 1,
                        "home": 0,
                        "waypoints": [],
                        "moving": False,
                        "position_lost": False,
                    }
                ],
            }
        ).encode()
    )
    out = st.match_motors(
        state, [MotorIdentity("a", "f"), MotorIdentity("a", "g"), MotorIdentity("c", "f")]
    )
    assert out[0].saved is not None and out[0].problem is None
    assert out[1].problem is not None and "geometry" in out[1].problem
    assert out[2].problem == "not in the state file"


def test_the_size_bound_is_far_above_any_real_state() -> None:
    """64 motors (the most a config has), 64-character names, full tables of 255
    waypoints of the widest value, the mock's axes: the bound is 16 times that."""
    biggest = [
        st.SavedMotor(f"{i:064d}", "f" * 16, POS_MIN, POS_MIN, [POS_MIN] * WAYPOINTS, True, True)
        for i in range(64)
    ]
    size = len(st.SavedState(biggest, {"mock": {"axes": [-(1 << 62) + 1] * 64}}).to_bytes())
    assert size * 16 <= st.MAX_FILE_BYTES


def test_a_file_that_grows_past_the_bound_while_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "state.json"
    path.write_bytes(b" " * 100)
    real_read = os.read

    def growing(fd: int, n: int) -> bytes:
        return b" " * n if n > 1 else real_read(fd, n) or b" "  # never ends

    monkeypatch.setattr(os, "read", growing)
    with pytest.raises(StateError, match="more than the 4 MiB"):
        read_state(path)
