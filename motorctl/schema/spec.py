"""The schema's own objects: a key (`Key`), a table (`Table`), a table inside a table
(`Child`), a rule across keys (`Rule`), a section declared by other code (`Extension`), and
how a dataclass made a table by `@section` (motorctl/schema/fields.py) gives its `Table`
(`table_of`) and a key's default (`default_of`).

It holds no state: its declarations are frozen, and it runs on its caller's thread.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, TypeVar, cast

T = TypeVar("T")

REQUIRED: Final[Any] = type("Required", (), {"__repr__": lambda self: "REQUIRED"})()
"""A key or table without a default: leaving it out is an error."""

DEFAULTS: Final[Any] = type("Defaults", (), {"__repr__": lambda self: "DEFAULTS"})()
"""An absent table means: every key at its default."""

TABLE_ATTR: Final = "__motorctl_table__"
"""The attribute of a table's dataclass that holds its `Table` (set by `@section`)."""


Violation = tuple[str, Any, str]
"""(key path relative to the table, value, problem) reported by a Rule."""


@dataclass(frozen=True)
class Rule:
    """A rule across keys of one table; `keys` are the keys whose docs list it."""

    keys: tuple[str, ...]
    text: str
    check: Callable[[Mapping[str, Any]], Violation | None]


@dataclass(frozen=True)
class Key:
    """One key: kind ("int", "float", "bool", "str", "pairs"), default, bounds, meaning."""

    kind: str
    default: Any
    doc: str
    name: str = ""
    lo: float | None = None
    hi: float | str | None = None  # a str names an earlier key in scope (this or a parent table)
    lo_open: bool = False
    choices: tuple[str, ...] | Callable[[], tuple[str, ...]] = ()
    choices_note: str | Callable[[], str] = ""
    enum: type[enum.Enum] | None = None  # choices convert to this enum's members
    pattern: str | None = None
    pattern_text: str = ""
    check: Callable[[str], str | None] | None = None  # extra string check -> problem or None
    check_text: str = ""
    check_listing: Callable[[], str] | None = None  # accepted values, listed in errors
    optional: bool = False
    unique: bool = False
    indexed_default: bool = False  # default is a format string with {index}
    default_text: str | None = None

    def choice_list(self) -> tuple[str, ...]:
        return self.choices() if callable(self.choices) else self.choices

    def choice_note(self) -> str:
        return self.choices_note() if callable(self.choices_note) else self.choices_note


@dataclass(frozen=True)
class Table:
    """A table's schema, read from its dataclass by `table_of`."""

    cls: type[Any]
    doc: str
    keys: tuple[Key, ...]
    children: tuple[Child, ...]
    rules: tuple[Rule, ...] = ()
    prose: str = ""  # docs/config.md text shown above the key table
    notes: str = ""  # docs/config.md text shown below it
    extensible: bool = False  # has a `sections` field that Extensions fill
    retired: tuple[tuple[str, str], ...] = ()  # (key, why): accepted, ignored, a notice

    def retired_why(self, name: str) -> str | None:
        return next((why for key, why in self.retired if key == name), None)

    def extended(self, extensions: Sequence[Extension], path: str = "") -> Table:
        """This table with the extensions placed at `path` ("" or "motors", "pins.x"...)."""
        children = []
        for child in self.children:
            sub = join(path, child.name)
            children.append(dataclasses.replace(child, table=child.table.extended(extensions, sub)))
        rules = list(self.rules)
        for ext in extensions:
            if ext.parent != path:
                continue
            if not self.extensible:
                raise TypeError(f"{self.cls.__name__} takes no extension sections ({ext.name})")
            if any(ext.name == n for n in self.names()):
                raise TypeError(f"section name {ext.name!r} is taken in {self.cls.__name__}")
            children.append(ext.child())
            rules.extend(ext.rules)
        return dataclasses.replace(self, children=tuple(children), rules=tuple(rules))

    def names(self) -> list[str]:
        return [k.name for k in self.keys] + [c.name for c in self.children]


@dataclass(frozen=True)
class Child:
    """A table or an array of tables inside a table. `absent` is the raw value used when it is
    missing: DEFAULTS for {}, REQUIRED for an error, or None for "no such thing" (None)."""

    name: str
    table: Table
    array: bool = False
    min_items: int = 0
    max_items: int = 0
    absent: Any = DEFAULTS
    absent_text: str = "all defaults"
    owner: str = ""  # an Extension's owner; its value lands in the parent's `sections`

    @property
    def extension(self) -> bool:
        """True for a section owned elsewhere (an Extension)."""
        return bool(self.owner)


@dataclass(frozen=True)
class Extension:
    """A section owned by other code, placed into an extensible table at load time.

    `parent` is the key path of that table: "" for the top level, "motors" for every
    [[motors]] entry, "pins" for every [[pins]] entry. `rules` join the parent's rules (they
    see the parent's values, this section's under `name`).
    """

    parent: str
    name: str
    cls: type[Any]
    owner: str  # who declares it, for the docs ("the mock backend")
    absent: Any = DEFAULTS
    absent_text: str = "all defaults"
    rules: tuple[Rule, ...] = ()

    def child(self) -> Child:
        return Child(
            self.name,
            table_of(self.cls),
            absent=self.absent,
            absent_text=self.absent_text,
            owner=self.owner,
        )


class Sectioned:
    """Mixin of an extensible config dataclass: `section(Cls)` reads an extension's value."""

    sections: Mapping[type[Any], Any]

    def section(self, cls: type[T]) -> T:
        """The value of the extension section declared by dataclass `cls`."""
        try:
            value = self.sections[cls]
        except KeyError:
            raise KeyError(f"no config section {cls.__name__} in {type(self).__name__}") from None
        return cast(T, value)


def table_of(cls: type[Any]) -> Table:
    """The schema of a dataclass made a table by `@section`."""
    spec = cls.__dict__.get(TABLE_ATTR)
    if not isinstance(spec, Table):
        raise TypeError(f"{cls.__name__} is not a config table (no @section)")
    return spec


def default_of(cls: type[Any], name: str) -> Any:
    """The declared default of key ``name`` of the table ``cls``: for a record outside the
    config that takes the same value, so that it is written once."""
    for key in table_of(cls).keys:
        if key.name == name:
            return key.default
    raise KeyError(f"{cls.__name__} declares no key {name!r}")


def join(path: str, name: str) -> str:
    """The key path of ``name`` in the table at ``path`` ("" for the top level)."""
    return f"{path}.{name}" if path else name
