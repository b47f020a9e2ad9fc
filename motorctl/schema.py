"""A small declarative schema for TOML configuration (Klipper style), generic and dependency-free.

Over 500 lines on purpose: one engine whose declarations, parser and docs renderer read
the same ``Key``/``Table`` objects; split, each part would need the others' internals.

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
"""

from __future__ import annotations

import dataclasses
import datetime
import enum
import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, TypeVar, cast

T = TypeVar("T")

REQUIRED: Final[Any] = type("Required", (), {"__repr__": lambda self: "REQUIRED"})()
"""A key or table without a default: leaving it out is an error."""

DEFAULTS: Final[Any] = type("Defaults", (), {"__repr__": lambda self: "DEFAULTS"})()
"""An absent table means: every key at its default."""

DEFAULT_NOTE: Final = " (the default value; set the key explicitly)"

_KEY: Final = "motorctl.schema.key"
_CHILD: Final = "motorctl.schema.child"
_SECTIONS: Final = "motorctl.schema.sections"
_GIVEN: Final = "motorctl.schema.given"
_TABLE_ATTR: Final = "__motorctl_table__"


class ConfigError(Exception):
    """A configuration that cannot be used; the message says where, what and what is accepted."""


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
            sub = _join(path, child.name)
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


# --------------------------------------------------------------------------------------------
# Declaring keys: each helper returns a dataclass field that carries the declaration.


def _field(key: Key) -> Any:
    return dataclasses.field(metadata={_KEY: key})


def integer(
    default: Any,
    lo: int,
    hi: int | str,
    doc: str,
    *,
    optional: bool = False,
    unique: bool = False,
    default_text: str | None = None,
) -> Any:
    """An integer key in lo..hi (`hi` may name an earlier key in scope). `default` None with
    optional=True: the key may be left unset; REQUIRED: it must be written."""
    return _field(
        Key(
            "int",
            default,
            doc,
            lo=lo,
            hi=hi,
            optional=optional,
            unique=unique,
            default_text=default_text,
        )
    )


def number(default: float, lo: float, hi: float | str, doc: str, *, lo_open: bool = False) -> Any:
    """A float key (integers accepted) in lo..hi, or in (lo, hi] with lo_open=True."""
    return _field(Key("float", default, doc, lo=lo, hi=hi, lo_open=lo_open))


def boolean(default: bool, doc: str) -> Any:
    """A true/false key."""
    return _field(Key("bool", default, doc))


def choice(
    default: str,
    choices: tuple[str, ...] | type[enum.Enum] | Callable[[], tuple[str, ...]],
    doc: str,
    *,
    note: str | Callable[[], str] = "",
) -> Any:
    """A string key from a fixed list; with an Enum class the value becomes its member (the
    choices are the members' values; a StrEnum member still equals its string)."""
    enum_cls: type[enum.Enum] | None = None
    if isinstance(choices, type) and issubclass(choices, enum.Enum):
        enum_cls = choices
        listed: tuple[str, ...] | Callable[[], tuple[str, ...]] = tuple(
            str(m.value) for m in choices
        )
    else:
        listed = cast(tuple[str, ...] | Callable[[], tuple[str, ...]], choices)
    return _field(Key("str", default, doc, choices=listed, choices_note=note, enum=enum_cls))


def text(
    default: str,
    doc: str,
    *,
    pattern: str | None = None,
    pattern_text: str = "",
    check: Callable[[str], str | None] | None = None,
    check_text: str = "",
    check_listing: Callable[[], str] | None = None,
    unique: bool = False,
    indexed_default: bool = False,
    default_text: str | None = None,
) -> Any:
    """A string key checked by a regular expression `pattern` or a `check` function
    (value -> problem or None; `check_text` says what is accepted, `check_listing` lists it)."""
    return _field(
        Key(
            "str",
            default,
            doc,
            pattern=pattern,
            pattern_text=pattern_text,
            check=check,
            check_text=check_text,
            check_listing=check_listing,
            unique=unique,
            indexed_default=indexed_default,
            default_text=default_text,
        )
    )


def pairs(default: list[list[int]], doc: str) -> Any:
    """An array of [pin, pin] pairs of pin numbers 0..255 (a tuple of int pairs in code)."""
    return _field(Key("pairs", default, doc))


def table(cls: type[Any], *, absent: Any = DEFAULTS, absent_text: str = "all defaults") -> Any:
    """A sub-table of dataclass `cls`; `absent` None makes the field None when it is left out."""
    return dataclasses.field(
        metadata={_CHILD: Child("", table_of(cls), absent=absent, absent_text=absent_text)}
    )


def tables(
    cls: type[Any],
    min_items: int,
    max_items: int,
    *,
    absent: Any = DEFAULTS,
    absent_text: str = "none",
) -> Any:
    """An array of tables of dataclass `cls` (a tuple in code)."""
    child = Child(
        "",
        table_of(cls),
        array=True,
        min_items=min_items,
        max_items=max_items,
        absent=absent,
        absent_text=absent_text,
    )
    return dataclasses.field(metadata={_CHILD: child})


def extension_sections() -> Any:
    """The `sections` field of an extensible dataclass (see `Sectioned`)."""
    return dataclasses.field(default_factory=dict, metadata={_SECTIONS: True})


def given(default: Any, *, compare: bool = True) -> Any:
    """A field that is not a key: the loader passes its value (`Parser.build(..., name=v)`).
    ``compare`` False: two configs that differ only here are equal (notices about the file)."""
    return dataclasses.field(default=default, compare=compare, metadata={_GIVEN: True})


_ANNOTATION: Final = {
    "int": "int",
    "float": "float",
    "bool": "bool",
    "str": "str",
    "pairs": "tuple[tuple[int, int], ...]",
}


def section(
    doc: str,
    *,
    rules: Sequence[Rule] = (),
    prose: str = "",
    notes: str = "",
    retired: Mapping[str, str] | None = None,
) -> Callable[[type[T]], type[T]]:
    """Make a frozen dataclass a config table (apply it above `@dataclass(frozen=True)`).

    Every field must be declared with a helper of this module, except `sections`
    (`extension_sections()`). The field's annotation is checked against the key's kind.
    ``retired``: keys of earlier releases that mean nothing now, with why: a file that writes
    one still loads (any value), and the parser records a notice that names it
    (`Parser.notices`), so that old files keep working and their owners learn what changed.
    """
    gone = tuple((retired or {}).items())

    def apply(cls: type[T]) -> type[T]:
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"@section goes above @dataclass: {cls.__name__}")
        keys: list[Key] = []
        children: list[Child] = []
        extensible = False
        for f in dataclasses.fields(cls):
            # `from __future__ import annotations` leaves the annotation as written; without
            # it, name the type the same way.
            annotation = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
            annotation = annotation or str(f.type)
            if _KEY in f.metadata:
                key = dataclasses.replace(f.metadata[_KEY], name=f.name)
                if key.enum is not None:
                    expected = key.enum.__name__
                else:
                    expected = _ANNOTATION[key.kind] + (" | None" if key.optional else "")
                if annotation != expected:
                    raise TypeError(f"{cls.__name__}.{f.name}: annotate it `{expected}`")
                keys.append(key)
            elif _CHILD in f.metadata:
                child = dataclasses.replace(f.metadata[_CHILD], name=f.name)
                name = child.table.cls.__name__
                expected = f"tuple[{name}, ...]" if child.array else name
                if child.absent is None:
                    expected += " | None"
                if annotation != expected:
                    raise TypeError(f"{cls.__name__}.{f.name}: annotate it `{expected}`")
                children.append(child)
            elif _SECTIONS in f.metadata:
                extensible = True
            elif _GIVEN in f.metadata:
                pass
            else:
                raise TypeError(f"{cls.__name__}.{f.name} is not declared with motorctl.schema")
        taken = {k.name for k in keys} | {c.name for c in children}
        if clash := taken & {name for name, _ in gone}:
            raise TypeError(f"{cls.__name__}: retired keys still declared: {sorted(clash)}")
        spec = Table(
            cls, doc, tuple(keys), tuple(children), tuple(rules), prose, notes, extensible, gone
        )
        setattr(cls, _TABLE_ATTR, spec)
        return cls

    return apply


def table_of(cls: type[Any]) -> Table:
    """The schema of a dataclass made a table by `@section`."""
    spec = cls.__dict__.get(_TABLE_ATTR)
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


# --------------------------------------------------------------------------------------------
# Formatting


def num(value: float) -> str:
    """A bound as people write it: 200000, not 200000.0."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def toml_value(value: Any, limit: int = 80) -> str:
    """A value written as in TOML, shortened to `limit` characters."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, enum.Enum):
        text = json.dumps(str(value.value), ensure_ascii=False)
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
    elif isinstance(value, float):
        text = "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        if math.isfinite(value):
            text = repr(value)
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(toml_value(v, limit) for v in value) + "]"
    elif isinstance(value, dict):
        inner = ", ".join(f"{k} = {toml_value(v, limit)}" for k, v in value.items())
        text = "{ " + inner + " }" if inner else "{}"
    elif isinstance(value, datetime.date | datetime.time):
        text = value.isoformat()
    else:
        text = str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def toml_type(value: Any) -> str:
    """The TOML type name of a parsed value."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, datetime.datetime):
        return "date-time"
    if isinstance(value, datetime.date):
        return "date"
    if isinstance(value, datetime.time):
        return "time"
    return type(value).__name__


def type_text(key: Key) -> str:
    """The type column of docs/config.md."""
    base = {
        "int": "integer",
        "float": "number",
        "bool": "boolean",
        "str": "string",
        "pairs": "array of [pin, pin]",
    }[key.kind]
    return base + " (optional)" if key.optional else base


def accepted(key: Key, scope: Mapping[str, Any] | None = None) -> str:
    """What a key accepts; with `scope`, bounds that name other keys show their values."""
    hi_text = ""
    if isinstance(key.hi, str):
        hi_text = key.hi
        if scope is not None and key.hi in scope:
            hi_text += f" ({key.hi} = {num(scope[key.hi])})"
    elif key.hi is not None:
        hi_text = num(key.hi)
    if key.kind in ("int", "float"):
        noun = "an integer" if key.kind == "int" else "a number"
        assert key.lo is not None
        if key.lo_open or isinstance(key.hi, str):
            op = ">" if key.lo_open else ">="
            text = f"{noun} {op} {num(key.lo)} and <= {hi_text}"
        else:
            text = f"{noun} in {num(key.lo)}..{hi_text}"
        if key.optional:
            text += ", or leave it unset"
        if key.default is REQUIRED:
            text += " (required)"
    elif key.kind == "bool":
        text = "true or false"
    elif key.kind == "pairs":
        text = "an array of [pin, pin] pairs of pin numbers 0..255"
    elif key.choices:
        text = "one of " + ", ".join(json.dumps(c) for c in key.choice_list())
        note = key.choice_note()
        if note:
            text += f" ({note})"
    elif key.pattern is not None:
        text = f"a string of {key.pattern_text}"
    else:
        text = key.check_text
    if key.unique:
        text += ", unique"
    return text


def header(path: str, array: bool) -> str:
    """How a table at a key path is written: [link], [[motors]], [motors.homing]."""
    plain = re.sub(r"\[\d*\]", "", path)
    return f"[[{plain}]]" if array else f"[{plain}]"


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


# --------------------------------------------------------------------------------------------
# Validation


class Parser:
    """Walks a parsed TOML document along the schema; the first problem raises ConfigError."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.defaulted: set[str] = set()  # key paths that took their default value
        self.notices: list[str] = []  # retired keys the file wrote, each with why

    def error(self, path: str, value: Any, problem: str, accepted: str) -> ConfigError:
        shown = f"{path} = {toml_value(value)}" if value is not REQUIRED else path
        return ConfigError(f"{self.source}: {shown}: {problem}; accepted: {accepted}")

    def build(self, spec: Table, raw: Any, **extra: Any) -> Any:
        """The dataclass of the top-level table `spec` built from the document `raw`."""
        return self._build(spec, self.table(spec, raw, "", "the top level", {}), extra)

    def table(
        self,
        spec: Table,
        raw: Any,
        path: str,
        where: str,
        scope: Mapping[str, Any],
        index: int = 0,
    ) -> dict[str, Any]:
        """Validated values of one table (sub-tables built), keyed by name."""
        if not isinstance(raw, dict):
            raise self.error(path, raw, f"wrong type ({toml_type(raw)})", f"a table {where}")
        allowed = sorted(spec.names())
        for name in raw:
            if name not in allowed and spec.retired_why(name) is None:
                listed = f"keys in {where}" if path else "top-level keys"
                raise ConfigError(
                    f"{self.source}: unknown key '{_join(path, name)}'; "
                    f"accepted {listed}: {', '.join(allowed)}"
                )
            why = spec.retired_why(name)
            if why is not None:
                self.notices.append(
                    f"{self.source}: '{_join(path, name)}' is retired and "
                    f"ignored: {why}; fix: remove it"
                )
        values: dict[str, Any] = {}
        inner = dict(scope)
        for key in spec.keys:
            values[key.name] = self.key(key, raw, _join(path, key.name), inner, index)
            inner[key.name] = values[key.name]
        for child in spec.children:
            values[child.name] = self.child(child, raw.get(child.name, REQUIRED), path, inner)
        for rule in spec.rules:
            violation = rule.check(values)
            if violation is not None:
                at, value, problem = violation
                at = _join(path, at)
                # a default value the rule refuses: say so (not for a key that is missing)
                if value is not REQUIRED and re.sub(r"\[\d+\]$", "", at) in self.defaulted:
                    problem += DEFAULT_NOTE
                raise self.error(at, value, problem, rule.text)
        return values

    @staticmethod
    def _build(spec: Table, values: dict[str, Any], extra: Mapping[str, Any]) -> Any:
        kwargs = dict(extra)
        sections: dict[type[Any], Any] = {}
        for child in spec.children:
            if child.extension:
                sections[child.table.cls] = values[child.name]
            else:
                kwargs[child.name] = values[child.name]
        for key in spec.keys:
            kwargs[key.name] = values[key.name]
        if spec.extensible:
            kwargs["sections"] = sections
        return spec.cls(**kwargs)

    def child(self, child: Child, raw: Any, parent: str, scope: Mapping[str, Any]) -> Any:
        """A sub-table or array of tables of the table at `parent`, built."""
        spec = child.table
        path = _join(parent, child.name)
        where = header(path, child.array)
        count = f"{child.min_items}..{child.max_items} {where} tables"
        if raw is REQUIRED:
            if child.absent is REQUIRED:
                needed = f"{count} (a config needs at least one)"
                raise self.error(path, REQUIRED, "missing", needed)
            if child.absent is None:
                return None
            raw = {} if child.absent is DEFAULTS else child.absent
        if not child.array:
            return self._build(spec, self.table(spec, raw, path, where, scope), {})
        if not isinstance(raw, list):
            raise self.error(
                path, raw, f"wrong type ({toml_type(raw)})", f"an array of tables: {count}"
            )
        if not child.min_items <= len(raw) <= child.max_items:
            raise self.error(path, REQUIRED, f"{len(raw)} entries", count)
        items = []
        seen: dict[str, dict[Any, int]] = {k.name: {} for k in spec.keys if k.unique}
        for i, item_raw in enumerate(raw):
            item_path = f"{path}[{i}]"
            values = self.table(spec, item_raw, item_path, where, scope, i)
            for key in spec.keys:
                if not key.unique:
                    continue
                value = values[key.name]
                if value in seen[key.name]:
                    first = seen[key.name][value]
                    raise self.error(
                        f"{item_path}.{key.name}",
                        value,
                        f"duplicate ({path}[{first}].{key.name} is also {toml_value(value)})",
                        f"a value used by no other {where} entry",
                    )
                seen[key.name][value] = i
            items.append(self._build(spec, values, {}))
        return tuple(items)

    def key(
        self, key: Key, raw: Mapping[str, Any], path: str, scope: Mapping[str, Any], index: int
    ) -> Any:
        """The validated value of one key (its default when absent)."""
        if key.name in raw:
            return self.convert(key, raw[key.name], path, scope)
        if key.default is REQUIRED:
            raise self.error(path, REQUIRED, "missing", accepted(key))
        if key.optional:
            return None
        if key.indexed_default:
            return str(key.default).format(index=index)
        self.defaulted.add(path)
        return self.convert(key, key.default, path, scope, DEFAULT_NOTE)

    def convert(
        self, key: Key, value: Any, path: str, scope: Mapping[str, Any], note: str = ""
    ) -> Any:
        """Type- and range-check one value; floats accept integers."""
        what = accepted(key, scope)
        type_problem = f"wrong type ({toml_type(value)})"
        if key.kind in ("int", "float"):
            number_types = int if key.kind == "int" else int | float
            if isinstance(value, bool) or not isinstance(value, number_types):
                raise self.error(path, value, type_problem, what)
            lo = key.lo
            hi = scope[key.hi] if isinstance(key.hi, str) else key.hi
            assert lo is not None and hi is not None
            in_range = (value > lo if key.lo_open else value >= lo) and value <= hi
            if not in_range:
                raise self.error(path, value, "out of range" + note, what)
            return float(value) if key.kind == "float" else value
        if key.kind == "bool":
            if not isinstance(value, bool):
                raise self.error(path, value, type_problem, what)
            return value
        if key.kind == "str":
            if not isinstance(value, str):
                raise self.error(path, value, type_problem, what)
            if key.choices and value not in key.choice_list():
                raise self.error(path, value, "unknown value", what)
            if key.pattern is not None and re.fullmatch(key.pattern, value) is None:
                raise self.error(path, value, "not a valid name", what)
            if key.check is not None:
                problem = key.check(value)
                if problem is not None:
                    if key.check_listing is not None:
                        what = f"{what}: {key.check_listing()}"
                    raise self.error(path, value, problem, what)
            return key.enum(value) if key.enum is not None else value
        return self.pairs(value, path, what)

    def pairs(self, value: Any, path: str, what: str) -> tuple[tuple[int, int], ...]:
        """An array of [pin, pin] pairs."""
        if not isinstance(value, list):
            raise self.error(path, value, f"wrong type ({toml_type(value)})", what)
        for i, pair in enumerate(value):
            ok = (
                isinstance(pair, list)
                and len(pair) == 2
                and all(isinstance(p, int) and not isinstance(p, bool) for p in pair)
            )
            if not ok:
                raise self.error(f"{path}[{i}]", pair, "not a [pin, pin] pair", what)
            if not all(0 <= p <= 255 for p in pair):
                raise self.error(f"{path}[{i}]", pair, "pin number out of range", what)
        return tuple((a, b) for a, b in value)


# --------------------------------------------------------------------------------------------
# Description (for docs/config.md and tests)


Row = tuple[str, str, str, str]
"""(key path, type, default, accepted values and meaning) of one key or table."""


def default_text(key: Key) -> str:
    """The default column: what a file without the key gets."""
    if key.default_text is not None:
        return key.default_text
    if key.default is REQUIRED:
        return "required"
    if key.kind == "float":
        return repr(float(key.default))
    return toml_value(key.default)


def describe(spec: Table, prefix: str = "", notes: dict[str, list[str]] | None = None) -> list[Row]:
    """A row for every key and sub-table of `spec`, depth first; arrays written `motors[]`."""
    notes = {} if notes is None else notes
    rows: list[Row] = []
    for rule in spec.rules:
        for name in rule.keys:
            notes.setdefault(_join(prefix, name), []).append(rule.text)
    for key in spec.keys:
        path = _join(prefix, key.name)
        what = "; ".join([accepted(key), *notes.get(path, [])])
        rows.append((path, type_text(key), default_text(key), f"{what}. {key.doc}"))
    for child in spec.children:
        rows.extend(describe_child(child, prefix, notes))
    return rows


def describe_child(child: Child, prefix: str, notes: dict[str, list[str]]) -> list[Row]:
    """The row of one sub-table and those of its keys."""
    path = _join(prefix, child.name)
    where = header(path, child.array)
    if child.array:
        kind, what = "array of tables", f"{child.min_items}..{child.max_items} {where} tables"
    else:
        kind, what = "table", f"a table {where}"
    rows = [(path, kind, child.absent_text, f"{what}. {child.table.doc}")]
    return rows + describe(child.table, path + "[]" if child.array else path, notes)
