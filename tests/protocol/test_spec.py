"""The words the command table is written in (protocol/spec.py): a command declared with
:func:`command` is a frozen dataclass of its parameters, its entry filled in from the
declaration; the error codes' own meanings."""

from __future__ import annotations

import dataclasses

import pytest

from motorctl.protocol.spec import (
    PRECEDENCE,
    Answer,
    Command,
    ErrorCode,
    Gives,
    Motion,
    Param,
    command,
    param,
)

N = Param("u8", "N", "a number", metavar="N")
FLAG = Param("bool", "Flag", "a flag", shown="flag", option="--flag", default=False)


@command(0x40, Answer("ACK"), (Gives(ErrorCode.INVALID_ADDRESS, "no motor {motor}"),), cli=("x",))
class DoSomeThing(Command):
    """Do something to MOTOR.

    More words that are not the summary."""

    motor: int = param(N)
    flag: bool = param(FLAG)


def test_a_declared_command_is_a_frozen_dataclass_with_its_entry() -> None:
    cmd = DoSomeThing(3, True)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cmd.motor = 4  # type: ignore[misc]
    with pytest.raises(TypeError):
        DoSomeThing(3)  # type: ignore[call-arg]
    spec = DoSomeThing.spec
    assert DoSomeThing.code == spec.code == 0x40 and spec.name == "DoSomeThing"
    assert spec.summary == "Do something to MOTOR"
    assert spec.handler == "do_some_thing"
    assert [(p.name, p.wire, p.size) for p in spec.params] == [
        ("motor", "u8", 1),
        ("flag", "bool", 1),
    ]
    assert spec.used_bytes == 2 and spec.param("flag") is not None and spec.param("x") is None
    assert spec.motion is None and spec.remedy_args == ()
    assert hash(spec) == hash(dataclasses.replace(spec))  # immutable through and through
    assert spec.gives_code(ErrorCode.INVALID_ADDRESS) is spec.gives[0]
    assert spec.gives_code(ErrorCode.MOTOR_ERROR) is None
    assert N.name == ""  # the declaration is left as it was; the entry holds a named copy


def test_a_motion_and_a_remedy_are_declared_with_it() -> None:
    @command(0x41, Answer("ACK when queued"), (), cli=("y",), motion=Motion(""), remedy="fix it")
    class Spin(Command):
        """Spin."""

        motor: int = param(N)

    assert Spin.spec.motion == Motion("") and Spin.spec.remedy_said == "Spin fixes it"
    said = {
        r: dataclasses.replace(Spin.spec, remedy=r).remedy_said
        for r in ("clear it", "empty it", "reach it", "go")
    }
    assert said == {
        "clear it": "Spin clears it",
        "empty it": "Spin empties it",
        "reach it": "Spin reaches it",
        "go": "Spin goes",
    }


def test_each_error_code_has_a_name_a_short_form_and_a_meaning() -> None:
    assert set(PRECEDENCE) == set(ErrorCode) and len(PRECEDENCE) == len(ErrorCode)
    for code in ErrorCode:
        template, plain = code.means
        assert code.label and code.short == f"E{code - 0xE0}" and template and plain
        assert "{" not in plain
    assert ErrorCode.FULL_WAYPOINT_BUFFER.means[0].format(motor=2) == (
        "motor 2's waypoint table is full"
    )
