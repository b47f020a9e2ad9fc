"""The command table: every command of the protocol, declared once (PROTOCOL.md §3-5).

Each command is a frozen dataclass, its fields its parameters in wire order (B1 onwards),
declared with :func:`~motorctl.protocol.spec.command` (the words: :mod:`motorctl.protocol.spec`):
its code, its answer, the errors it can give in the contract's precedence (and what each
means for it), whether it is a motion command, its words on ``motorctl``'s command line.
:data:`COMMANDS` lists them in code order. Everything else reads them: the codec
(:mod:`motorctl.protocol.codec`), the daemon's dispatcher (a handler per command, by name:
:attr:`~motorctl.protocol.spec.Spec.handler`), the client and its CLI, the conversation and
trace text, the replay's judge, the Wireshark dissector (client/dissector.py) and
docs/protocol.md's command table (checked by tests/docs/test_command_table.py).

Besides the errors a command declares, the link gives these to any frame: E1 for a frame
that fails its checks (checksum, code, padding: before all else), E0 for a frame beyond the
held-frame buffer behind a WaitMoved (never a StopMove), E4 for a command whose execution
failed inside the daemon (docs/protocol.md).

Pure declarations: no I/O, no clock, no mutable state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from enum import IntEnum
from typing import TypeVar, cast

from motorctl.protocol.spec import (
    Answer,
    Command,
    ErrorCode,
    Gives,
    Motion,
    Param,
    Scale,
    command,
    param,
)

__all__ = [
    "BY_CODE",
    "BY_NAME",
    "COMMANDS",
    "MOTION_COMMANDS",
    "Command",
    "CommandCode",
    "ConfigPin",
    "DcMove",
    "GetAbsPos",
    "GetPin",
    "GoHome",
    "InitMove",
    "IsReady",
    "Move",
    "MoveTo",
    "MoveToWayPoint",
    "SaveHome",
    "SaveWayPoint",
    "SetPin",
    "StopMove",
    "WaitMoved",
]

E = ErrorCode
K = TypeVar("K")

# --- units (PROTOCOL.md §3; the factors are [units] settings with these defaults) -------------

RUN_SPEED = Scale("run_speed_factor", 4096.0, "step/s")
MOVE_SPEED = Scale("move_speed_factor", 4.0, "step/s")
RAMP = Scale("accel_factor", 16.0, "step/s^2")

# --- parameters -------------------------------------------------------------------------------

DEFAULT = "the motor's default"
MOTOR = Param("u8", "Motor", "motor number: 0 is the first motor of the daemon's config")
MOTOR = replace(MOTOR, metavar="MOTOR")
DIRECTION = Param(
    "bool", "Direction", "up (counting up) or down", short="dir", shown="word", words=("up", "down")
)
POSITION = Param("s24", "Position (steps)", "absolute target", short="pos", unit="steps")
POSITION = replace(POSITION, metavar="POS")
SPEED = Param("u8", "Speed", "SPEED byte", zero=DEFAULT, option="--speed", default=0, metavar="N")
ACC = Param("u8", "Acceleration", "ACC byte", scale=RAMP, zero=DEFAULT, option="--acc", default=0)
ACC = replace(ACC, metavar="N")
DEC = replace(ACC, label="Deceleration", help="DEC byte", option="--dec")
SPEED_RUN = replace(SPEED, scale=RUN_SPEED)
SPEED_MOVE = replace(SPEED, scale=MOVE_SPEED)
PIN = Param("u8", "Pin", "pin number, as the daemon's config numbers its IO pins", metavar="PIN")
HIGH_LOW = ("high", "low")
LEVEL = Param("bool", "Level", "the level to drive", key="value", shown="level", words=HIGH_LOW)
WAYPOINT = Param("u8", "Waypoint", "waypoint number, as SaveWayPoint gave it", metavar="N")
MS = "ms"

# --- answers ----------------------------------------------------------------------------------

ACK = Answer("ACK")
QUEUED = Answer("ACK when queued")
READY = Param("bool", "Ready", "idle with an empty queue", shown="flag", words=("ready", "busy"))
LEVEL_READ = Param("bool", "Level", "the pin's level", shown="level", words=HIGH_LOW)
NUMBER = Param("u8", "Waypoint", "the saved waypoint's number", name="waypoint")

# --- errors -----------------------------------------------------------------------------------

NO_MOTOR = Gives(E.INVALID_ADDRESS, "no motor {motor}")
NO_PIN = Gives(E.INVALID_ADDRESS, "no pin {pin}")
FAULT = Gives(E.MOTOR_ERROR, "motor {motor} has a latched fault", ("StopMove",))
UNUSABLE = Gives(
    E.MOTOR_ERROR,
    "motor {motor} has a latched fault or has lost its position",
    ("StopMove", "InitMove"),
)
QUEUE_FULL = Gives(E.FULL_BUFFER, "motor {motor}'s motion queue is full")
MOVING = Gives(
    E.MOTOR_NOT_READY, "motor {motor} is moving or has commands queued; it must be at rest"
)
LINE_FAILED = Gives(E.MOTOR_ERROR, "pin {pin}'s line failed (hardware error)")
NOT_SAVED = Gives(
    E.MOTOR_ERROR,
    "motor {motor} has a latched fault or has lost its position, or the state file cannot "
    "be written",
    ("StopMove", "InitMove"),
)

# --- the commands, in code order --------------------------------------------------------------


@command(
    0x00,
    QUEUED,
    (NO_MOTOR, FAULT, QUEUE_FULL),
    motion=Motion("zero", in_direction=True, homes=True),
    cli=("init",),
    remedy="home it",
)
class InitMove(Command):
    """Home MOTOR towards its end stop (position becomes 0)."""

    motor: int = param(MOTOR)
    direction: bool = param(
        replace(DIRECTION, help="where its end stop is: up (counting up) or down")
    )
    speed: int = param(replace(SPEED_RUN, zero="the motor's homing speed (homing.speed)"))
    acc: int = param(ACC)
    dec: int = param(DEC)


@command(
    0x01,
    QUEUED,
    (
        NO_MOTOR,
        Gives(
            E.INVALID_COMMAND,
            "target {position} is outside motor {motor}'s soft limits or its driver chip's range",
        ),
        UNUSABLE,
        QUEUE_FULL,
    ),
    motion=Motion("position"),
    cli=("moveto",),
)
class MoveTo(Command):
    """Queue a move of MOTOR to the absolute step position POS."""

    motor: int = param(MOTOR)
    direction: bool = param(
        replace(DIRECTION, help="DIR byte: used on rotary axes only", option="--dir", default=True)
    )
    position: int = param(POSITION)
    speed: int = param(SPEED_MOVE)
    acc: int = param(ACC)
    dec: int = param(DEC)


@command(
    0x02,
    Answer("held", held="timeout_ms"),
    (
        NO_MOTOR,
        FAULT,
        Gives(E.MOTOR_NOT_READY, "motor {motor} still moving when TIMEOUT_MS ran out"),
    ),
    cli=("wait",),
)
class WaitMoved(Command):
    """Wait until MOTOR is idle (E3 after TIMEOUT_MS)."""

    motor: int = param(MOTOR)
    timeout_ms: int = param(
        Param(
            "u16",
            "Timeout (ms)",
            "device-side timeout",
            unit=MS,
            zero="answer at once (E3 if it moves)",
            metavar="TIMEOUT_MS",
            default=60000,
        )
    )


@command(
    0x03,
    Answer("TRUE/FALSE", replace(READY, name="ready"), line="motor {motor} {text}"),
    (NO_MOTOR, FAULT),
    cli=("ready",),
)
class IsReady(Command):
    """Is MOTOR idle with an empty queue?"""

    motor: int = param(MOTOR)


@command(0x04, QUEUED, (NO_MOTOR, UNUSABLE, QUEUE_FULL), motion=Motion("", True), cli=("move",))
class Move(Command):
    """Run MOTOR continuously until stopped."""

    motor: int = param(MOTOR)
    direction: bool = param(DIRECTION)
    speed: int = param(SPEED_RUN)
    acc: int = param(ACC)
    dec: int = param(DEC)


@command(
    0x05,
    ACK,
    (NO_MOTOR, Gives(E.MOTOR_ERROR, "motor {motor}'s fault remains (its driver still reports it)")),
    cli=("stop",),
    remedy="clear it",
)
class StopMove(Command):
    """Stop MOTOR and empty its queue."""

    motor: int = param(MOTOR)
    hard: bool = param(
        Param(
            "bool",
            "Hard stop",
            "stop without a ramp",
            shown="flag",
            names=("yes", "no (ramp)"),
            option="--hard",
            default=False,
        )
    )


@command(
    0x06,
    Answer(
        "position",
        Param(
            "s24", "Position (steps)", "the position", short="pos", unit="steps", name="position"
        ),
        line="motor {motor} at {value}",
    ),
    (NO_MOTOR,),
    cli=("pos",),
)
class GetAbsPos(Command):
    """Print the position of MOTOR."""

    motor: int = param(MOTOR)


@command(
    0x07,
    ACK,
    (NO_PIN, Gives(E.INVALID_COMMAND, "pin {pin} is an input", ("ConfigPin",)), LINE_FAILED),
    cli=("pin", "set"),
)
class SetPin(Command):
    """Drive output PIN high or low."""

    pin: int = param(PIN)
    high: bool = param(LEVEL)


@command(
    0x08,
    Answer("0/1", replace(LEVEL_READ, name="value"), line="pin {pin} {text}"),
    (NO_PIN, LINE_FAILED),
    cli=("pin", "get"),
)
class GetPin(Command):
    """Read PIN."""

    pin: int = param(PIN)


@command(
    0x09,
    ACK,
    (NO_PIN, LINE_FAILED),
    cli=("pin", "config"),
    remedy="make it an output",
    remedy_args={"output": True},
)
class ConfigPin(Command):
    """Make PIN an input or an output."""

    pin: int = param(PIN)
    output: bool = param(
        Param(
            "bool",
            "Output",
            "in: an input, out: an output",
            shown="flag",
            words=("out", "in"),
            aliases=(("output", True), ("input", False)),
            names=("output", "input"),
        )
    )


@command(0x0A, ACK, (NO_MOTOR, NOT_SAVED, MOVING), cli=("home", "save"))
class SaveHome(Command):
    """Store the current position of MOTOR as home."""

    motor: int = param(MOTOR)


@command(
    0x0B,
    QUEUED,
    (
        NO_MOTOR,
        Gives(
            E.INVALID_COMMAND,
            "motor {motor}'s home is outside its soft limits or its driver chip's range",
        ),
        UNUSABLE,
        QUEUE_FULL,
    ),
    motion=Motion("home"),
    cli=("home", "go"),
)
class GoHome(Command):
    """Queue a move of MOTOR to its home."""

    motor: int = param(MOTOR)


@command(
    0x0C,
    Answer("waypoint number", NUMBER, line="waypoint {value} saved on motor {motor}"),
    (
        NO_MOTOR,
        NOT_SAVED,
        MOVING,
        Gives(E.FULL_WAYPOINT_BUFFER, "motor {motor}'s waypoint table is full"),
    ),
    cli=("waypoint", "save"),
)
class SaveWayPoint(Command):
    """Store the current position of MOTOR as a waypoint."""

    motor: int = param(MOTOR)


@command(
    0x0D,
    QUEUED,
    (
        NO_MOTOR,
        Gives(
            E.INVALID_COMMAND,
            "waypoint {waypoint} is outside motor {motor}'s soft limits or its driver chip's range",
        ),
        Gives(E.INVALID_WAYPOINT, "no waypoint {waypoint} saved on motor {motor}"),
        UNUSABLE,
        QUEUE_FULL,
    ),
    motion=Motion("waypoint"),
    cli=("waypoint", "go"),
)
class MoveToWayPoint(Command):
    """Queue a move of MOTOR to waypoint N."""

    motor: int = param(MOTOR)
    waypoint: int = param(WAYPOINT)
    speed: int = param(SPEED_MOVE)
    acc: int = param(ACC)
    dec: int = param(DEC)


@command(
    0x0E,
    ACK,
    (
        Gives(E.INVALID_ADDRESS, "no DC motor configured"),
        Gives(E.MOTOR_ERROR, "the DC motor's bridge failed (hardware error)"),
    ),
    cli=("dc",),
)
class DcMove(Command):
    """Run the DC motor TIME_MS, then brake (default) or coast."""

    direction: bool = param(
        Param(
            "bool",
            "Direction",
            "the DC motor's direction",
            short="dir",
            shown="word",
            words=("forward", "reverse"),
        )
    )
    time_ms: int = param(
        Param("u16", "Run time (ms)", "run time", unit=MS, zero="stop at once", metavar="TIME_MS")
    )
    hiz: bool = param(
        Param(
            "bool",
            "Coast at the end (GO_HiZ)",
            "end with the bridge in high impedance (GO_HiZ TRUE, coasting)",
            shown="flag",
            names=("yes", "no (brake)"),
            option="--hiz",
            off_option="--brake",
            off_help="end with the bridge braking (GO_HiZ FALSE, default)",
            default=False,
        )
    )


#: every command, in code order
COMMANDS: tuple[type[Command], ...] = (
    InitMove,
    MoveTo,
    WaitMoved,
    IsReady,
    Move,
    StopMove,
    GetAbsPos,
    SetPin,
    GetPin,
    ConfigPin,
    SaveHome,
    GoHome,
    SaveWayPoint,
    MoveToWayPoint,
    DcMove,
)


def index(
    table: Sequence[type[Command]], key: Callable[[type[Command]], K]
) -> dict[K, type[Command]]:
    """``table`` by ``key``; ValueError when two commands share one (a code, a name)."""
    out = {key(c): c for c in table}
    if len(out) != len(table):
        raise ValueError("the command table declares a code or a name twice")
    return out


#: the commands by code (B0) and by name ("MoveTo")
BY_CODE: dict[int, type[Command]] = index(COMMANDS, lambda c: c.code)
BY_NAME: dict[str, type[Command]] = index(COMMANDS, lambda c: c.spec.name)
#: the motion commands: they go into the motor's queue (E0 when it is full) and their ACK
#: waits for "moving" to be durable (PROTOCOL.md, "Motion commands")
MOTION_COMMANDS: tuple[type[Command], ...] = tuple(c for c in COMMANDS if c.spec.motion)


def _codes() -> type[IntEnum]:
    members = {"_".join(s.upper() for s in c.spec.handler.split("_")): c.code for c in COMMANDS}
    return cast(type[IntEnum], IntEnum("CommandCode", members))


#: the command codes by name (INIT_MOVE = 0x00, ...), as an enum
CommandCode = _codes()
