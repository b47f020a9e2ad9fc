"""The words the command table (:mod:`motorctl.protocol.commands`) is written in: what a
command's parameter, answer, error and motion are, and the error codes (PROTOCOL.md §5).

A command is declared once, as a frozen dataclass decorated with :func:`command`: its code,
its answer, the errors it can give (in the contract's precedence), whether it is a motion
command, and its command-line words; each parameter as ``name: type = param(DECLARATION)``,
in wire order, with its wire size, its unit (and unit factor), its range and how it is shown
and typed on the command line. The codec, the dispatcher, the client, the CLI, the
conversation and trace text, the replay's judge, the Wireshark dissector and the docs read
the declaration; none restates it.

Pure declarations: no I/O, no clock, no mutable state.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, ClassVar, Literal, TypeVar, cast, dataclass_transform

#: a position's range: 24-bit two's complement (PROTOCOL.md section 1)
POS_MIN = -8_388_608
POS_MAX = 8_388_607
#: the most waypoints a motor's table holds (a motor's configured table may be smaller): E5
#: beyond it (PROTOCOL.md, "SaveHome / SaveWayPoint")
WAYPOINTS = 255


class ErrorCode(IntEnum):
    """Error codes sent in R1 of an error response."""

    FULL_BUFFER = 0xE0
    INVALID_COMMAND = 0xE1
    INVALID_ADDRESS = 0xE2
    MOTOR_NOT_READY = 0xE3
    MOTOR_ERROR = 0xE4
    FULL_WAYPOINT_BUFFER = 0xE5
    INVALID_WAYPOINT = 0xE6

    @property
    def label(self) -> str:
        """The name the original specification uses."""
        return _ERROR_LABELS[self]

    @property
    def short(self) -> str:
        """Short form E0..E6."""
        return f"E{self.value - 0xE0}"

    @property
    def means(self) -> tuple[str, str]:
        """What the code means where a command declares no meaning of its own for it: a
        template naming the command's parameters (``{motor}``), and the words without them."""
        return _ERROR_MEANS[self]


E = ErrorCode
_ERROR_LABELS: dict[ErrorCode, str] = {
    E.FULL_BUFFER: "Full Buffer",
    E.INVALID_COMMAND: "Invalid Command",
    E.INVALID_ADDRESS: "Invalid Address",
    E.MOTOR_NOT_READY: "Motor not ready",
    E.MOTOR_ERROR: "Motor Error",
    E.FULL_WAYPOINT_BUFFER: "Full Way Point Buffer",
    E.INVALID_WAYPOINT: "Invalid Way Point",
}
_REFUSED = "the frame was refused: a wrong checksum, an unknown command or non-zero padding"
_ERROR_MEANS: dict[ErrorCode, tuple[str, str]] = {
    E.FULL_BUFFER: ("motor {motor}'s motion queue is full", "buffer full"),
    E.INVALID_COMMAND: (_REFUSED, _REFUSED),
    E.INVALID_ADDRESS: ("no motor {motor}", "no such motor or pin"),
    E.MOTOR_NOT_READY: ("motor {motor} not ready", "motor not ready"),
    E.MOTOR_ERROR: (
        "motor {motor} has a latched fault or has lost its position",
        "a latched fault or a lost position",
    ),
    E.FULL_WAYPOINT_BUFFER: ("motor {motor}'s waypoint table is full", "waypoint table full"),
    E.INVALID_WAYPOINT: ("no waypoint {waypoint} saved on motor {motor}", "no such waypoint"),
}
#: PROTOCOL.md §5: when several errors apply to a command, the first of these wins (E1 for a
#: frame's checksum, code or padding comes before them all; E0 and E5 never meet)
PRECEDENCE = (
    E.INVALID_ADDRESS,
    E.INVALID_COMMAND,
    E.INVALID_WAYPOINT,
    E.MOTOR_ERROR,
    E.MOTOR_NOT_READY,
    E.FULL_BUFFER,
    E.FULL_WAYPOINT_BUFFER,
)

# --- parameters -------------------------------------------------------------------------------

Wire = Literal["u8", "u16", "s24", "bool"]
SIZE: dict[Wire, int] = {"u8": 1, "u16": 2, "s24": 3, "bool": 1}
_HIGHEST: dict[Wire, int] = {"u8": 0xFF, "u16": 0xFFFF, "s24": POS_MAX, "bool": 1}
#: how a value is shown in text, in ``motorctl trace --json`` and in Wireshark: a number,
#: a flag (true/false), a level (1/0 in JSON, true/false in text), a word (up/down)
Shown = Literal["number", "flag", "level", "word"]


@dataclass(frozen=True)
class Scale:
    """A unit factor (PROTOCOL.md §3): the value times ``[units] setting`` is ``unit``;
    ``default`` is the contract's (the original's) factor."""

    setting: str
    default: float
    unit: str

    def text(self) -> str:
        return f"x {self.default:g} {self.unit} ([units] {self.setting})"


@dataclass(frozen=True)
class Param:
    """One parameter of a command (or an answer's value): its wire form and how it reads.

    ``name`` is the dataclass field's (filled in by :func:`command`); ``key`` the name in
    ``motorctl trace --json`` and Wireshark (the name unless it differs), ``short`` in
    :func:`motorctl.protocol.codec.describe`. A boolean's ``words`` (true, false) are typed
    on the command line and, when ``shown`` is "word", printed; ``names`` name its values in
    Wireshark (the words unless they differ). ``option`` makes it a command-line option (a
    flag for a boolean without words; ``off_option`` its opposite, said by ``off_help``),
    ``default`` its value when not typed (None: it must be)."""

    wire: Wire
    label: str
    help: str
    key: str = ""
    short: str = ""
    unit: str = ""
    scale: Scale | None = None
    zero: str = ""
    shown: Shown = "number"
    words: tuple[str, str] | None = None
    aliases: tuple[tuple[str, bool], ...] = ()
    names: tuple[str, str] | None = None
    metavar: str = ""
    option: str = ""
    off_option: str = ""
    off_help: str = ""
    default: int | bool | None = None
    name: str = ""

    @property
    def size(self) -> int:
        return SIZE[self.wire]

    @property
    def lo(self) -> int:
        return POS_MIN if self.wire == "s24" else 0

    @property
    def hi(self) -> int:
        return _HIGHEST[self.wire]

    @property
    def field(self) -> str:
        """Its name in JSON and Wireshark."""
        return self.key or self.name

    @property
    def said(self) -> str:
        """Its name in a command's text."""
        return self.short or self.name

    @property
    def value_names(self) -> tuple[str, str]:
        """A boolean's values as Wireshark names them (true, false)."""
        names = self.names or self.words
        return names if names is not None else ("true", "false")

    def text(self, value: int | bool) -> str:
        """``value`` in a command's or an answer's text."""
        if self.wire != "bool":
            return str(value)
        if self.shown == "word" and self.words is not None:
            return self.words[0] if value else self.words[1]
        return "true" if value else "false"

    def json(self, value: int | bool) -> int | bool | str:
        """``value`` as ``motorctl trace --json`` types it."""
        if self.wire != "bool":
            return int(value)
        if self.shown == "word":
            return self.text(value)
        return int(bool(value)) if self.shown == "level" else bool(value)

    def typed(self, value: int | bool) -> str:
        """``value`` as typed on the command line: a boolean's word, a number."""
        if self.wire == "bool" and self.words is not None:
            return self.words[0] if value else self.words[1]
        return str(int(value))

    @property
    def placeholder(self) -> str:
        """What stands for it on a command line: its metavar, a boolean's words ("up|down")."""
        if self.metavar:
            return self.metavar
        return "|".join(self.words) if self.words is not None else self.name.upper()

    def choices(self) -> dict[str, bool]:
        """A boolean's words as typed on the command line (case-insensitive)."""
        if self.words is None:
            return {}
        return {self.words[0]: True, self.words[1]: False, **dict(self.aliases)}

    def range_text(self) -> str:
        """What it takes, for the docs and ``--help``: "0..255 x 4 step/s ([units]
        move_speed_factor); 0 = the motor's default", "0 = down, else up",
        "-8388608..8388607 steps"."""
        if self.wire == "bool":
            yes, no = self.words or self.value_names
            return f"0 = {no}, else {yes}"
        text = f"{self.lo}..{self.hi}"
        if self.unit:
            text += f" {self.unit}"
        if self.scale is not None:
            text += f" {self.scale.text()}"
        if self.zero:
            text += f"; 0 = {self.zero}"
        return text


# --- answers, errors, motions -----------------------------------------------------------------


@dataclass(frozen=True)
class Answer:
    """What a command's ACK carries. ``value``: R1.. read as that parameter (None: nothing,
    a bare ACK); ``doc``: the docs' answer column; ``line``: what ``motorctl`` prints (the
    command's parameters and ``value``/``text`` by name); ``held``: the parameter that bounds
    how long the answer may be held (ms)."""

    doc: str
    value: Param | None = None
    line: str = "ok"
    held: str = ""

    def text(self, value: int | bool) -> str:
        """An ACK's text for this command: "ready", "pos=1200", "waypoint=0"."""
        p = self.value
        if p is None:
            return "ok"
        if p.wire == "bool" and p.words is not None:
            return p.words[0] if value else p.words[1]
        return f"{p.said}={p.text(value)}"


@dataclass(frozen=True)
class Gives:
    """An error a command can give and what it means for it: a template naming the command's
    parameters; ``fix``: the commands that clear it, by name."""

    code: ErrorCode
    means: str
    fix: tuple[str, ...] = ()


@dataclass(frozen=True)
class Motion:
    """A motion command (PROTOCOL.md §4): queued (E0 when the queue is full), acknowledged
    when accepted, ``moving`` made durable before its ACK. ``ends``: where it ends when it
    runs to its end: at its parameter of that name ("position"), at the saved ``waypoint``,
    at ``home``, at ``zero`` (homing), or "" (it runs until stopped); ``in_direction``: it
    runs the way its ``direction`` says."""

    ends: Literal["position", "waypoint", "home", "zero", ""]
    in_direction: bool = False
    homes: bool = False


@dataclass(frozen=True)
class Spec:
    """One command of the table (see :func:`command`)."""

    code: int
    name: str
    summary: str
    params: tuple[Param, ...]
    answer: Answer
    gives: tuple[Gives, ...]
    motion: Motion | None
    cli: tuple[str, ...]
    remedy: str
    remedy_args: tuple[tuple[str, int | bool], ...]

    @property
    def handler(self) -> str:
        """The name of its handler (the dispatcher's method): MoveToWayPoint ->
        move_to_way_point."""
        return re.sub(r"(?<!^)(?=[A-Z])", "_", self.name).lower()

    @property
    def remedy_said(self) -> str:
        """What it does named as a fix, said of it: "StopMove clears it" (its remedy, the
        verb in the third person)."""
        verb, _, rest = self.remedy.partition(" ")
        if verb.endswith(("s", "sh", "ch", "x", "z", "o")):
            verb += "es"
        elif verb.endswith("y") and verb[-2:-1] not in ("a", "e", "i", "o", "u"):
            verb = verb[:-1] + "ies"
        else:
            verb += "s"
        return f"{self.name} {verb} {rest}".rstrip()

    @property
    def used_bytes(self) -> int:
        """Parameter bytes after B0 (the rest of B1..B8 is padding)."""
        return sum(p.size for p in self.params)

    def param(self, name: str) -> Param | None:
        return next((p for p in self.params if p.name == name), None)

    def gives_code(self, code: ErrorCode) -> Gives | None:
        return next((g for g in self.gives if g.code is code), None)


@dataclass(frozen=True)
class Command:
    """A command (the base of the table's classes); ``code`` is B0, ``spec`` its entry."""

    code: ClassVar[int]
    spec: ClassVar[Spec]


_PARAM = "motorctl.param"
C = TypeVar("C", bound=type[Command])


def param(p: Param) -> Any:
    """A command's parameter: ``motor: int = param(MOTOR)``."""
    return dataclasses.field(metadata={_PARAM: p})


@dataclass_transform(frozen_default=True, field_specifiers=(param,))
def command(
    code: int,
    answer: Answer,
    gives: tuple[Gives, ...],
    *,
    cli: tuple[str, ...],
    motion: Motion | None = None,
    remedy: str = "",
    remedy_args: Mapping[str, int | bool] | None = None,
) -> Callable[[C], C]:
    """Declare a command: a frozen dataclass whose fields are its parameters in wire order,
    its docstring's first line what it does (``--help``). ``cli``: its words on the command
    line; ``remedy``: what it does when named as a fix ("clear it"), with ``remedy_args``."""

    def declare(cls: C) -> C:
        made = cast(C, dataclass(frozen=True)(cls))
        params = tuple(
            dataclasses.replace(f.metadata[_PARAM], name=f.name) for f in dataclasses.fields(made)
        )
        summary = (cls.__doc__ or "").strip().splitlines()[0].rstrip(".")
        made.code = code
        made.spec = Spec(
            code,
            cls.__name__,
            summary,
            params,
            answer,
            gives,
            motion,
            cli,
            remedy,
            tuple((remedy_args or {}).items()),
        )
        return made

    return declare
