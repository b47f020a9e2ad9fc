"""The command table (protocol/commands.py): each declaration is whole and agrees with
itself and with the contract (PROTOCOL.md §3-5), so that what reads it (codec, dispatcher,
CLI, trace, judge, dissector, docs) can rely on it."""

from __future__ import annotations

import dataclasses
import string

import pytest

from motorctl.protocol import commands
from motorctl.protocol.codec import FRAME_LEN
from motorctl.protocol.commands import (
    BY_CODE,
    BY_NAME,
    COMMANDS,
    MOTION_COMMANDS,
    CommandCode,
    DcMove,
    GetAbsPos,
    GetPin,
    InitMove,
    IsReady,
    MoveTo,
    SaveWayPoint,
    StopMove,
    WaitMoved,
)
from motorctl.protocol.spec import PRECEDENCE, Command, ErrorCode

E = ErrorCode
NAMES = [c.spec.name for c in COMMANDS]


def each(ids: list[str] = NAMES) -> pytest.MarkDecorator:
    return pytest.mark.parametrize("cls", COMMANDS, ids=ids)


def test_the_table_is_the_contracts_commands_in_code_order() -> None:
    assert [c.code for c in COMMANDS] == list(range(0x0F))
    assert NAMES == [
        "InitMove",
        "MoveTo",
        "WaitMoved",
        "IsReady",
        "Move",
        "StopMove",
        "GetAbsPos",
        "SetPin",
        "GetPin",
        "ConfigPin",
        "SaveHome",
        "GoHome",
        "SaveWayPoint",
        "MoveToWayPoint",
        "DcMove",
    ]
    assert {c.code: c for c in COMMANDS} == BY_CODE
    assert dict(zip(NAMES, COMMANDS, strict=True)) == BY_NAME
    assert {int(c) for c in CommandCode} == set(BY_CODE)
    assert CommandCode["MOVE_TO_WAY_POINT"] == 0x0D
    declared = {c for c in Command.__subclasses__() if c.__module__ == commands.__name__}
    assert declared == set(COMMANDS)  # none declared and left out


def test_the_motion_commands_are_the_contracts() -> None:
    """PROTOCOL.md §4: InitMove, MoveTo, Move, GoHome, MoveToWayPoint."""
    assert [c.spec.name for c in MOTION_COMMANDS] == [
        "InitMove",
        "MoveTo",
        "Move",
        "GoHome",
        "MoveToWayPoint",
    ]


@each()
def test_a_command_fits_its_frame_and_names_its_fields(cls: type[Command]) -> None:
    spec = cls.spec
    assert cls.spec.used_bytes <= FRAME_LEN - 2
    assert [p.name for p in spec.params] == [f.name for f in dataclasses.fields(cls)]
    assert spec.summary and spec.handler.isidentifier() and spec.handler.islower()
    for p in spec.params:
        assert p.label and p.help
        if p.wire == "bool":
            assert p.shown in ("flag", "level", "word")
            assert p.words is not None or p.option, "a flag without words is an option"
            assert p.shown != "word" or p.words is not None
        else:
            assert p.shown == "number" and p.words is None
            assert p.placeholder.isupper() or p.option, "a number's placeholder"
        if p.default is not None:
            assert p.lo <= int(p.default) <= p.hi


@each()
def test_its_errors_are_in_the_contracts_precedence(cls: type[Command]) -> None:
    codes = [g.code for g in cls.spec.gives]
    assert len(codes) == len(set(codes))
    assert codes == sorted(codes, key=PRECEDENCE.index)
    fields = {p.name for p in cls.spec.params}
    for g in cls.spec.gives:
        named = {n for _, n, _, _ in string.Formatter().parse(g.means) if n}
        assert named <= fields, f"{g.means!r} names what {cls.spec.name} does not have"
        for fix in g.fix:
            assert BY_NAME[fix].spec.remedy, f"{fix} is named as a fix but has no remedy"


@each()
def test_a_motion_says_where_it_ends(cls: type[Command]) -> None:
    m = cls.spec.motion
    fields = {p.name for p in cls.spec.params}
    if m is None:
        return
    assert "motor" in fields and cls.spec.answer.doc == "ACK when queued"
    assert E.FULL_BUFFER in [g.code for g in cls.spec.gives]  # the queue
    assert m.ends in ("", "zero", "home") or m.ends in fields
    assert not m.in_direction or "direction" in fields
    assert m.ends or m.in_direction  # one that runs until stopped runs some way


def test_the_answers() -> None:
    assert IsReady.spec.answer.text(True) == "ready" and IsReady.spec.answer.text(False) == "busy"
    assert GetAbsPos.spec.answer.text(-5) == "pos=-5"
    assert GetPin.spec.answer.text(True) == "high"
    assert SaveWayPoint.spec.answer.text(0) == "waypoint=0"
    assert StopMove.spec.answer.text(0) == "ok"
    assert WaitMoved.spec.answer.held == "timeout_ms"
    assert [c for c in COMMANDS if c.spec.answer.held] == [WaitMoved]


def test_the_remedies() -> None:
    """What the commands named in a fix do (the journal's and motorctl's words)."""
    assert {c.spec.name: c.spec.remedy_said for c in COMMANDS if c.spec.remedy} == {
        "InitMove": "InitMove homes it",
        "StopMove": "StopMove clears it",
        "ConfigPin": "ConfigPin makes it an output",
    }
    for cls in COMMANDS:
        assert {n for n, _ in cls.spec.remedy_args} <= {p.name for p in cls.spec.params}


def test_the_command_line_words_are_unique_and_grouped() -> None:
    words = [c.spec.cli for c in COMMANDS]
    assert len(set(words)) == len(words) and all(1 <= len(w) <= 2 for w in words)
    groups = {w[0] for w in words if len(w) == 2}
    assert not groups & {w[0] for w in words if len(w) == 1}  # a group is no command


def test_a_parameter_reads_as_the_table_says() -> None:
    direction, position, speed = (MoveTo.spec.param(n) for n in ("direction", "position", "speed"))
    assert direction is not None and position is not None and speed is not None
    assert (direction.said, direction.text(True), direction.json(False)) == ("dir", "up", "down")
    assert (position.said, position.lo, position.hi, position.json(-3)) == (
        "pos",
        -8388608,
        8388607,
        -3,
    )
    assert speed.range_text() == (
        "0..255 x 4 step/s ([units] move_speed_factor); 0 = the motor's default"
    )
    level = commands.SetPin.spec.param("high")
    assert level is not None and (level.field, level.json(True), level.text(True)) == (
        "value",
        1,
        "true",
    )
    hard = StopMove.spec.param("hard")
    assert hard is not None and hard.range_text() == "0 = no (ramp), else yes"
    dc = DcMove.spec.param("direction")
    assert dc is not None and (dc.text(False), dc.placeholder) == ("reverse", "forward|reverse")
    output = commands.ConfigPin.spec.param("output")
    assert output is not None and output.choices() == {
        "out": True,
        "in": False,
        "output": True,
        "input": False,
    }
    homing = InitMove.spec.param("speed")
    assert homing is not None and homing.scale is not None and homing.scale.default == 4096


def test_a_code_or_name_declared_twice_is_refused() -> None:
    assert commands.index(COMMANDS, lambda c: c.code) == BY_CODE
    with pytest.raises(ValueError, match="twice"):
        commands.index((*COMMANDS, MoveTo), lambda c: c.code)
    renamed = type("MoveTo", (StopMove,), {})  # another class of a name the table has
    with pytest.raises(ValueError, match="twice"):
        commands.index((*COMMANDS, renamed), lambda c: c.spec.name)
