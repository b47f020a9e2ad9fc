"""How values and keys are written, in error messages and in docs/config.md: a bound
(`num`), a value as in TOML (`toml_value`) and its TOML type (`toml_type`), what a key
accepts (`accepted`), its type and default columns (`type_text`, `default_text`), a table's
header (`header`).

It holds no state: its declarations are frozen, and it runs on its caller's thread.
"""

from __future__ import annotations

import datetime
import enum
import json
import math
import re
from collections.abc import Mapping
from typing import Any

from motorctl.schema.spec import REQUIRED, Key


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
    if key.kind in ("int", "float"):
        text = _number_text(key, scope)
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


def _number_text(key: Key, scope: Mapping[str, Any] | None) -> str:
    """What a number key accepts: its bounds (an upper one that names another key with
    that key's value, where ``scope`` has it), unset or required."""
    hi_text = ""
    if isinstance(key.hi, str):
        hi_text = key.hi
        if scope is not None and key.hi in scope:
            hi_text += f" ({key.hi} = {num(scope[key.hi])})"
    elif key.hi is not None:
        hi_text = num(key.hi)
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
    return text


def header(path: str, array: bool) -> str:
    """How a table at a key path is written: [link], [[motors]], [motors.homing]."""
    plain = re.sub(r"\[\d*\]", "", path)
    return f"[[{plain}]]" if array else f"[{plain}]"


def default_text(key: Key) -> str:
    """The default column: what a file without the key gets."""
    if key.default_text is not None:
        return key.default_text
    if key.default is REQUIRED:
        return "required"
    if key.kind == "float":
        return repr(float(key.default))
    return toml_value(key.default)
