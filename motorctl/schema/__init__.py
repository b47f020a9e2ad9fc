"""A small declarative schema for TOML configuration (Klipper style), generic and dependency-free.

A config section is a frozen dataclass whose fields *are* the key declarations: each field is
made by one of the helpers below (`integer`, `number`, `boolean`, `choice`, `text`, `pairs`,
`table`, `tables`), which records the key's kind, default, bounds and documentation in the
field's metadata. The schema is read from those fields, so a key, its default, its bounds, its
doc and the attribute the code reads are one declaration, never matched by name. `@section`
adds what belongs to the table as a whole: its doc, prose for docs/config.md and the rules
that relate several keys. Example::

    @section("Timing of the widget.")
    @dataclass(frozen=True)
    class WidgetConfig:
        period_ms: float = number(10.0, 0.1, 1000, "How often the widget runs.")
        mode: str = choice("fast", ("fast", "slow"), "Which widget mode.")

`Parser` validates a parsed TOML document against a `Table` (`table_of(WidgetConfig)`) and
builds the dataclasses; the first problem raises `ConfigError` naming the source, the key path,
the value, the problem and what is accepted. Unknown keys are refused at every level.

Sections owned by other code (a hardware backend's `[gpiod]`, `[motors.mock]`...) are attached
to an extensible table as `Extension`s at load time: their values land in the parent's
`sections` mapping and are read with `parent.section(TheirConfig)`.

This module sits under every room (it imports nothing from motorctl), so that motion/ and hal/
can declare the sections they own without importing the daemon. It holds no state: the
declarations are frozen, a `Parser` lives for one parse on the caller's thread and blocks on
nothing.

Its parts, by what they declare (import from ``motorctl.schema``, which names them all):

- ``spec.py``: the schema's objects (``Key``, ``Table``, ``Child``, ``Rule``, ``Extension``,
  ``Sectioned``, ``REQUIRED``, ``DEFAULTS``) and ``table_of``/``default_of``;
- ``fields.py``: declaring a table: the key helpers and ``@section``;
- ``words.py``: how values and keys are written in messages and docs (``toml_value``,
  ``accepted``, ``header``...);
- ``parser.py``: ``Parser`` and ``ConfigError``, checking a document and building the config;
- ``rows.py``: ``describe``, a table row by row for docs/config.md.
"""

from __future__ import annotations

from motorctl.schema.fields import (
    boolean,
    choice,
    extension_sections,
    given,
    integer,
    number,
    pairs,
    section,
    table,
    tables,
    text,
)
from motorctl.schema.parser import DEFAULT_NOTE, ConfigError, Parser
from motorctl.schema.rows import Row, describe, describe_child
from motorctl.schema.spec import (
    DEFAULTS,
    REQUIRED,
    Child,
    Extension,
    Key,
    Rule,
    Sectioned,
    Table,
    Violation,
    default_of,
    table_of,
)
from motorctl.schema.words import (
    accepted,
    default_text,
    header,
    num,
    toml_type,
    toml_value,
    type_text,
)

__all__ = [
    "DEFAULTS",
    "DEFAULT_NOTE",
    "REQUIRED",
    "Child",
    "ConfigError",
    "Extension",
    "Key",
    "Parser",
    "Row",
    "Rule",
    "Sectioned",
    "Table",
    "Violation",
    "accepted",
    "boolean",
    "choice",
    "default_of",
    "default_text",
    "describe",
    "describe_child",
    "extension_sections",
    "given",
    "header",
    "integer",
    "num",
    "number",
    "pairs",
    "section",
    "table",
    "table_of",
    "tables",
    "text",
    "toml_type",
    "toml_value",
    "type_text",
]
