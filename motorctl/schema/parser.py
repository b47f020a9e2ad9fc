"""Checking a parsed TOML document against a `Table` and building its dataclasses
(`Parser`): the first problem raises `ConfigError` naming the source, the key path, the
value, the problem and what is accepted. Unknown keys are refused at every level.

It holds no state of its own: a `Parser` lives for one parse, on its caller's thread, and
blocks on nothing.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, Final

from motorctl.schema.spec import DEFAULTS, REQUIRED, Child, Key, Table, join
from motorctl.schema.words import accepted, header, toml_type, toml_value

DEFAULT_NOTE: Final = " (the default value; set the key explicitly)"


class ConfigError(Exception):
    """A configuration that cannot be used; the message says where, what and what is accepted."""


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
                    f"{self.source}: unknown key '{join(path, name)}'; "
                    f"accepted {listed}: {', '.join(allowed)}"
                )
            why = spec.retired_why(name)
            if why is not None:
                self.notices.append(
                    f"{self.source}: '{join(path, name)}' is retired and "
                    f"ignored: {why}; fix: remove it"
                )
        values: dict[str, Any] = {}
        inner = dict(scope)
        for key in spec.keys:
            values[key.name] = self.key(key, raw, join(path, key.name), inner, index)
            inner[key.name] = values[key.name]
        for child in spec.children:
            values[child.name] = self.child(child, raw.get(child.name, REQUIRED), path, inner)
        for rule in spec.rules:
            violation = rule.check(values)
            if violation is not None:
                at, value, problem = violation
                at = join(path, at)
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
        path = join(parent, child.name)
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
        if key.kind in ("int", "float"):
            return self._number(key, value, path, scope, what, note)
        if key.kind == "bool":
            if not isinstance(value, bool):
                raise self.error(path, value, _wrong_type(value), what)
            return value
        if key.kind == "str":
            return self._string(key, value, path, what)
        return self.pairs(value, path, what)

    def _number(
        self, key: Key, value: Any, path: str, scope: Mapping[str, Any], what: str, note: str
    ) -> int | float:
        """An integer, or a float (integers accepted), within the key's bounds (an upper
        bound that names another key is that key's value in ``scope``)."""
        number_types = int if key.kind == "int" else int | float
        if isinstance(value, bool) or not isinstance(value, number_types):
            raise self.error(path, value, _wrong_type(value), what)
        lo = key.lo
        hi = scope[key.hi] if isinstance(key.hi, str) else key.hi
        assert lo is not None and hi is not None
        in_range = (value > lo if key.lo_open else value >= lo) and value <= hi
        if not in_range:
            raise self.error(path, value, "out of range" + note, what)
        return float(value) if key.kind == "float" else value

    def _string(self, key: Key, value: Any, path: str, what: str) -> Any:
        """A string from the key's choices (its enum's member, where it has one), of its
        pattern, or passing its check (whose listing joins what is accepted)."""
        if not isinstance(value, str):
            raise self.error(path, value, _wrong_type(value), what)
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


def _wrong_type(value: Any) -> str:
    return f"wrong type ({toml_type(value)})"
