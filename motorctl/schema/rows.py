"""A table described row by row, for docs/config.md and tests: every key and sub-table
with its type, its default, what it accepts and what it means.

It holds no state: its declarations are frozen, and it runs on its caller's thread.
"""

from __future__ import annotations

from motorctl.schema.spec import Child, Table, join
from motorctl.schema.words import accepted, default_text, header, type_text

Row = tuple[str, str, str, str]
"""(key path, type, default, accepted values and meaning) of one key or table."""


def describe(spec: Table, prefix: str = "", notes: dict[str, list[str]] | None = None) -> list[Row]:
    """A row for every key and sub-table of `spec`, depth first; arrays written `motors[]`."""
    notes = {} if notes is None else notes
    rows: list[Row] = []
    for rule in spec.rules:
        for name in rule.keys:
            notes.setdefault(join(prefix, name), []).append(rule.text)
    for key in spec.keys:
        path = join(prefix, key.name)
        what = "; ".join([accepted(key), *notes.get(path, [])])
        rows.append((path, type_text(key), default_text(key), f"{what}. {key.doc}"))
    for child in spec.children:
        rows.extend(describe_child(child, prefix, notes))
    return rows


def describe_child(child: Child, prefix: str, notes: dict[str, list[str]]) -> list[Row]:
    """The row of one sub-table and those of its keys."""
    path = join(prefix, child.name)
    where = header(path, child.array)
    if child.array:
        kind, what = "array of tables", f"{child.min_items}..{child.max_items} {where} tables"
    else:
        kind, what = "table", f"a table {where}"
    rows = [(path, kind, child.absent_text, f"{what}. {child.table.doc}")]
    return rows + describe(child.table, path + "[]" if child.array else path, notes)
