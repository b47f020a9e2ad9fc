"""The Wireshark dissector built from the command table (client/dissector.py): the template
knows no command, the built plugin holds the whole table (read back from its Lua tables),
and a command added to the table is dissected by tshark without an edit to the template.
Recordings of the real commands through tshark: tests/client/test_trace_files.py."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from motorctl.client import dissector
from motorctl.protocol.capture.format import CaptureInfo, Direction, Record
from motorctl.protocol.capture.writer import encode
from motorctl.protocol.codec import (
    COMMANDS,
    CodecOptions,
    ErrorCode,
    Response,
    encode_response,
)
from motorctl.protocol.spec import Answer, Command, Gives, Param, command, param
from tests.support import REPO
from tests.support.frames import raw_frame

TSHARK = shutil.which("tshark")
OPTS = CodecOptions()
TEMPLATE = dissector.TEMPLATE.read_text(encoding="utf-8")

ECHO = Param("u8", "Echo", "the byte to echo", metavar="N")
#: the made-up commands' codes: the first the table does not have
FREE = max(c.code for c in COMMANDS) + 1


@command(
    FREE,
    Answer("the byte", Param("u8", "Echo", "the byte echoed", name="echo")),
    (Gives(ErrorCode.INVALID_ADDRESS, "nobody to echo"),),
    cli=("made-up",),
)
class MadeUp(Command):
    """Echo N (a made-up command: not the protocol's)."""

    echo: int = param(ECHO)


def block(lua: str, name: str) -> str:
    """The body of ``local NAME = { ... }`` at the top level of the built plugin."""
    m = re.search(rf"^local {name} = {{\n(.*?)^}}", lua, re.M | re.S)
    assert m is not None, name
    return m[1]


def items(text: str) -> list[dict[str, str]]:
    """``{ key = "motor", wire = "u8", size = 1, ... }`` items, in order."""
    return [
        {k: v.strip('"') for k, v in re.findall(r'(\w+) = ("[^"]*"|\d+)', m)}
        for m in re.findall(r"\{ (key = [^}]*) \}", text)
    ]


def expected(p: Param) -> dict[str, str]:
    out = {"key": p.field, "wire": p.wire, "size": str(p.size), "said": p.said}
    if p.wire == "bool":
        yes, no = p.words or ("true", "false")
        out |= {"show": p.shown, "yes": yes, "no": no}
    return out


def test_the_template_knows_no_command() -> None:
    assert TEMPLATE.count(dissector.MARK) == 1
    for cls in COMMANDS:
        assert cls.spec.name not in TEMPLATE
    for code in ErrorCode:
        assert code.label not in TEMPLATE
    assert '"motorctl.motor"' not in TEMPLATE  # the fields too


def test_the_built_dissector_holds_the_whole_table() -> None:
    lua = dissector.render(TEMPLATE)
    names = dict(re.findall(r'\[0x([0-9A-F]{2})\] = "(\w+)"', block(lua, "COMMANDS")))
    assert {int(k, 16): v for k, v in names.items()} == {c.code: c.spec.name for c in COMMANDS}
    layout = block(lua, "LAYOUT")
    per_code = re.split(r"^    \[0x([0-9A-F]{2})\] = \{", layout, flags=re.M)[1:]
    pairs = zip(per_code[::2], per_code[1::2], strict=True)
    got = {int(code, 16): items(body) for code, body in pairs}
    assert got == {c.code: [expected(p) for p in c.spec.params] for c in COMMANDS}
    answers = re.findall(r"\[0x([0-9A-F]{2})\] = (\{[^}]*\})", block(lua, "ANSWERS"))
    want = {c.code: expected(c.spec.answer.value) for c in COMMANDS if c.spec.answer.value}
    assert {int(k, 16): items(v)[0] for k, v in answers} == want
    errors = re.findall(r'\[0x(E[0-9A-F])\] = "([^"]+)"', block(lua, "ERRORS"))
    assert {int(k, 16): v for k, v in errors} == {c.value: c.label for c in ErrorCode}
    fields = re.findall(
        r'^    (\w+) = ProtoField\.(\w+)\("motorctl\.(\w+)"', block(lua, "VALUE_FIELDS"), re.M
    )
    assert all(key == name for key, _, name in fields)
    keys = {p.field for c in COMMANDS for p in c.spec.params} | {"ready"}
    assert {key for key, _, _ in fields} == keys
    assert dict((k, t) for k, t, _ in fields)["position"] == "int32"
    assert dict((k, t) for k, t, _ in fields)["direction"] == "string"


def test_the_docs_name_every_field_of_the_table() -> None:
    """docs/trace.md, "Wireshark and tshark", names each field the table gives the plugin."""
    text = (REPO / "docs" / "trace.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`motorctl\.(\w+)`", text))
    assert set(dissector.fields()) <= named, set(dissector.fields()) - named


def test_the_mark_must_be_there_once() -> None:
    with pytest.raises(ValueError, match="once"):
        dissector.render("-- no mark\n")
    with pytest.raises(ValueError, match="once"):
        dissector.render(f"{dissector.MARK}\n{dissector.MARK}\n")


def test_a_field_declared_twice_differently_is_refused() -> None:
    @command(FREE + 1, Answer("ACK"), (), cli=("other",))
    class Other(Command):
        """A made-up command whose ``echo`` is two bytes."""

        echo: int = param(Param("u16", "Echo", "two bytes"))

    assert set(dissector.fields([MadeUp])) == {"echo"}
    with pytest.raises(ValueError, match="'echo' is declared twice differently"):
        dissector.fields([MadeUp, Other])


def test_main_writes_the_plugin_or_says_why_not(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "motorctl.lua"
    assert dissector.main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == dissector.render(TEMPLATE)
    assert dissector.main(["--output", str(tmp_path / "missing" / "x.lua")]) == 2
    assert capsys.readouterr().err.startswith(f"error: cannot write {tmp_path}/missing/x.lua")


@pytest.mark.skipif(TSHARK is None, reason="TSHARK IS MISSING: apt-get install tshark")
def test_a_command_added_to_the_table_is_dissected(tmp_path: Path) -> None:
    """The table plus a made-up command (its frames made by hand: the codec knows the
    protocol's table only): tshark names it, its field and its answer."""
    plugin = tmp_path / "motorctl.lua"
    plugin.write_text(dissector.render(TEMPLATE, (*COMMANDS, MadeUp)), encoding="utf-8")
    records = [
        Record(0, Direction.TO_DEVICE, raw_frame(bytes([FREE, 7]))),
        Record(1_000_000, Direction.TO_HOST, encode_response(Response.ok(b"\x07"), OPTS)),
        Record(2_000_000, Direction.TO_DEVICE, raw_frame(bytes([FREE, 9]))),
        Record(
            3_000_000,
            Direction.TO_HOST,
            encode_response(Response.error(ErrorCode.INVALID_ADDRESS), OPTS),
        ),
    ]
    capture = tmp_path / "made-up.pcapng"
    capture.write_bytes(encode(CaptureInfo(role="daemon"), records))
    fields = ["motorctl.kind", "motorctl.command", "motorctl.echo", "motorctl.answer"]
    args = [TSHARK or "tshark", "-X", f"lua_script:{plugin}", "-r", str(capture), "-T", "fields"]
    run = subprocess.run(
        [*args, *(a for f in fields for a in ("-e", f))],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0 and "lua" not in run.stderr.lower(), run.stderr
    rows = [line.split("\t") for line in run.stdout.splitlines()]
    assert rows == [
        ["command", "MadeUp", "7", ""],
        ["answer", "MadeUp", "7", "echo=7"],
        ["command", "MadeUp", "9", ""],
        ["answer", "MadeUp", "", "E2 Invalid Address"],
    ]
