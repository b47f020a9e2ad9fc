"""docs/protocol.md's command tables say what the command table (protocol/commands.py)
declares: "The command table" row for row (its parameters with their sizes, ranges and units,
its answer, whether it moves a motor, the errors it can give in precedence order), the codes,
names and answers of "Commands and the choices we made", and the motion queue's list of the
motion commands. On a difference the test prints the rows as they must read."""

from __future__ import annotations

import re

from motorctl.protocol.codec import COMMANDS, MOTION_COMMANDS, Command
from motorctl.protocol.spec import Param
from tests.support import REPO

PAGE = REPO / "docs" / "protocol.md"
HEAD = "| code | command | parameters after B0 | answer | motion | errors (first wins) |"


def cell(text: str) -> str:
    """Text as a Markdown table cell holds it."""
    return text.replace("|", "\\|")


def param_text(p: Param) -> str:
    """``motor`` 1 byte: 0..255, ``direction`` 1 byte: 0 = down, else up, ..."""
    size = f"{p.size} byte{'s' if p.size > 1 else ''}"
    return f"`{p.name}` {size}: {p.range_text()}"


def row(cls: type[Command]) -> str:
    spec = cls.spec
    params = "<br>".join(param_text(p) for p in spec.params) or "none"
    names = {p.name: p.placeholder for p in spec.params}
    errors = "<br>".join(f"{g.code.short} {g.means.format_map(names)}" for g in spec.gives)
    motion = "yes (queued)" if spec.motion is not None else "no"
    cells = [f"0x{spec.code:02X}", spec.name, params, spec.answer.doc, motion, errors]
    return "| " + " | ".join(cell(c) for c in cells) + " |"


def table_rows(text: str, head: str) -> list[str]:
    """The rows of the Markdown table whose header line is ``head`` (after its rule)."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(head)), len(lines))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(line)
    return rows


def test_the_command_table_is_the_tables() -> None:
    text = PAGE.read_text(encoding="utf-8")
    expected = [row(cls) for cls in COMMANDS]
    got = table_rows(text, HEAD)
    assert got == expected, "docs/protocol.md, The command table, must read:\n" + "\n".join(
        [HEAD, "|---|---|---|---|---|---|", *expected]
    )


def test_the_choices_name_each_command_with_its_code_and_answer() -> None:
    text = PAGE.read_text(encoding="utf-8")
    rows = table_rows(text, "| code | command | answer | notes |")
    cells = [[c.strip() for c in r.split(" | ")[:3]] for r in rows]
    want = [[f"| 0x{c.code:02X}", c.spec.name, c.spec.answer.doc] for c in COMMANDS]
    assert cells == want


def test_the_motion_queue_names_the_motion_commands() -> None:
    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    m = re.search(r"Motion commands \(([^)]*)\) are acknowledged when accepted", text)
    assert m is not None
    assert m[1].split(", ") == [c.spec.name for c in MOTION_COMMANDS]
