"""The Wireshark dissector, built from the command table: ``python3 -m
motorctl.client.dissector [--output FILE]`` writes client/wireshark/motorctl.lua.in with the
command table (motorctl.protocol.commands) where the template says ``@COMMAND_TABLE@``:
each command's code and name, its parameters in wire order (size, how each is shown, its
field), what its ACK carries, the error codes' names, and a Wireshark field per parameter
and answer value, named as ``motorctl trace --json`` names them (docs/trace.md).

The dissector is built, not kept: the Debian package's build writes it
(debian/rules), the tests build it to run tshark with, a pip install writes it with this
command; so a command added to the table is in Wireshark without an edit here.

Runs on the caller's thread; :func:`render` is computation, :func:`main` reads the template
and writes the result.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

from motorctl.protocol.codec import COMMANDS, Command, ErrorCode
from motorctl.protocol.spec import Param

Table = Sequence[type[Command]]

TEMPLATE = Path(__file__).resolve().parent / "wireshark" / "motorctl.lua.in"
MARK = "-- @COMMAND_TABLE@"
#: a Wireshark field's type by the parameter's wire form (a word: a string)
PROTO_FIELD = {"u8": "uint8", "u16": "uint16", "s24": "int32", "bool": "uint8"}


def _lua(text: str) -> str:
    """A Lua string literal."""
    escaped = text.replace("\\", "\\\\").replace('"', '\\"')
    return f'"{escaped}"'


def _item(p: Param) -> str:
    """A parameter (or an answer's value) as the dissector's tables hold it."""
    parts = [f"key = {_lua(p.field)}", f"wire = {_lua(p.wire)}", f"size = {p.size}"]
    parts.append(f"said = {_lua(p.said)}")
    if p.wire == "bool":
        yes, no = p.words if p.words is not None else ("true", "false")
        parts += [f"show = {_lua(p.shown)}", f"yes = {_lua(yes)}", f"no = {_lua(no)}"]
    return "{ " + ", ".join(parts) + " }"


def fields(commands: Table = COMMANDS) -> dict[str, Param]:
    """Every parameter and answer value of the table by its field name (the first
    declaration of each); ValueError where two declare one name differently for Wireshark."""
    out: dict[str, Param] = {}
    for cls in commands:
        value = cls.spec.answer.value
        for p in (*cls.spec.params, *([value] if value is not None else [])):
            seen = out.setdefault(p.field, p)
            if _proto_field(seen) != _proto_field(p):
                raise ValueError(
                    f"the field {p.field!r} is declared twice differently: "
                    f"{_proto_field(seen)} and {_proto_field(p)} ({cls.spec.name})"
                )
    return out


def _proto_field(p: Param) -> str:
    """The Wireshark field of a parameter: ``ProtoField.uint8("motorctl.motor", "Motor")``."""
    name = f'"motorctl.{p.field}", {_lua(p.label)}'
    if p.wire == "bool" and p.shown == "word":
        return f"ProtoField.string({name})"
    if p.wire == "bool":
        yes, no = p.value_names
        return f"ProtoField.uint8({name}, base.DEC, {{ [0] = {_lua(no)}, [1] = {_lua(yes)} }})"
    return f"ProtoField.{PROTO_FIELD[p.wire]}({name})"


def _lines(commands: Table) -> Iterator[str]:
    yield "-- generated from the command table (protocol/commands.py) by client/dissector.py"
    yield "local COMMANDS = {"
    for cls in commands:
        yield f"    [0x{cls.code:02X}] = {_lua(cls.spec.name)},"
    yield "}"
    yield "-- each command's parameters after B0, in wire order"
    yield "local LAYOUT = {"
    for cls in commands:
        yield f"    [0x{cls.code:02X}] = {{ -- {cls.spec.name}"
        for p in cls.spec.params:
            yield f"        {_item(p)},"
        yield "    },"
    yield "}"
    yield "-- what each command's ACK carries, where it carries something"
    yield "local ANSWERS = {"
    for cls in commands:
        value = cls.spec.answer.value
        if value is not None:
            yield f"    [0x{cls.code:02X}] = {_item(value)},"
    yield "}"
    yield "local ERRORS = {"
    for code in ErrorCode:
        yield f"    [0x{code.value:02X}] = {_lua(code.label)},"
    yield "}"
    yield "-- a field per parameter and answer value, named as motorctl trace --json names them"
    yield "local VALUE_FIELDS = {"
    for key, p in fields(commands).items():
        yield f"    {key} = {_proto_field(p)},"
    yield "}"


def render(template: str, commands: Table = COMMANDS) -> str:
    """The dissector: ``template`` with the command table (``commands``) where it says
    ``MARK`` (once); ValueError for a template without it, or with it twice."""
    if template.count(MARK) != 1:
        raise ValueError(f"the template must say {MARK!r} once, on a line of its own")
    return template.replace(MARK, "\n".join(_lines(commands)))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python3 -m motorctl.client.dissector",
        description="Write motorctl's Wireshark dissector (a Lua plugin) built from the command "
        "table: to stdout, or to FILE (docs/trace.md, 'Wireshark').",
    )
    parser.add_argument("--output", "-o", type=Path, metavar="FILE", help="write it here")
    args = parser.parse_args(argv)
    text = render(TEMPLATE.read_text(encoding="utf-8"))
    if args.output is None:
        sys.stdout.write(text)
        return 0
    try:
        args.output.write_text(text, encoding="utf-8")
    except OSError as exc:
        print(f"error: cannot write {args.output}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
