"""Declaring a table: each key a dataclass field made by a helper (`integer`, `number`,
`boolean`, `choice`, `text`, `pairs`, `table`, `tables`, `extension_sections`, `given`),
which carries its declaration in the field's metadata; `@section` reads those fields into
the class's `Table` (motorctl/schema/spec.py), checking each annotation against its key.

It holds no state: its declarations are frozen, and it runs on its caller's thread.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Final, TypeVar, cast

from motorctl.schema.spec import DEFAULTS, TABLE_ATTR, Child, Key, Rule, Table, table_of

T = TypeVar("T")

_KEY: Final = "motorctl.schema.key"
_CHILD: Final = "motorctl.schema.child"
_SECTIONS: Final = "motorctl.schema.sections"
_GIVEN: Final = "motorctl.schema.given"


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
        setattr(cls, TABLE_ATTR, spec)
        return cls

    return apply
