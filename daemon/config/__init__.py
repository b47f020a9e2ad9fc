"""The daemon's configuration: one TOML file checked against a declarative schema.

Split by owner:

- `motorctl.schema` (motorctl/schema/): the generic engine — key helpers, types, bounds,
  choices, tables and arrays of tables, unknown-key rejection, error messages. It lives
  below every room so that hal/ and motion/ can declare the sections they own.
- `model`: the core tables (link, units, hal, step_thread, dc, motors, pins); each key is a
  field of the dataclass the code reads, declared once with its default, bounds and doc.
- HAL backends' sections: declared next to each backend (hal/backends/<name>/config.py) and
  named in hal/registry.py; attached by `loader.schema()`.
- `loader`: parse and load a file, the embedded default and its commented text.
- `docs`: docs/config.md, generated (`python -m motorctl.daemon.config.docs --write`); it
  also says how to add a key or a section.

Any problem raises ConfigError naming the file, the key path, the problem and what is
accepted. Everything here is pure or reads one file on the caller's thread.
"""

from __future__ import annotations

from motorctl.daemon.config.loader import (
    EMBEDDED_SOURCE,
    default_config_text,
    load_config,
    parse_config,
    schema,
)
from motorctl.daemon.config.model import (
    Config,
    DcConfig,
    EndstopConfig,
    HalConfig,
    HomingConfig,
    LinkConfig,
    MotorConfig,
    PinConfig,
    StateConfig,
    TraceConfig,
    UnitsConfig,
)
from motorctl.motion.executors.config import StepThreadConfig
from motorctl.schema import ConfigError, Row, describe

__all__ = [
    "EMBEDDED_SOURCE",
    "Config",
    "ConfigError",
    "DcConfig",
    "EndstopConfig",
    "HalConfig",
    "HomingConfig",
    "LinkConfig",
    "MotorConfig",
    "PinConfig",
    "StateConfig",
    "StepThreadConfig",
    "TraceConfig",
    "UnitsConfig",
    "default_config_text",
    "describe_keys",
    "load_config",
    "parse_config",
    "schema",
]


def describe_keys() -> list[Row]:
    """(key path, type, default, accepted values and meaning) of every key and table.

    Arrays of tables are written `motors[]`; generated from the schema used to validate.
    """
    return describe(schema())
