"""Loading a config: the composed schema, the file reader and the embedded default.

`schema()` is the core model (`model.Config`) with every HAL backend's sections attached,
from the registry. `load_config(path)` reads and validates a file; `load_config(None)` is
the embedded default, a mock world described by `EMBEDDED_WORLD` (only what differs from the
keys' defaults); `default_config_text()` writes it out with every key and its doc.

Runs on the caller's thread; blocks only on reading the file.
"""

from __future__ import annotations

import codecs
import dataclasses
import errno
import os
import re
import stat
import textwrap
import tomllib
from typing import Any, Final

from motorctl.daemon.config.model import Config
from motorctl.daemon.state.files import kind
from motorctl.hal.registry import config_sections
from motorctl.schema import (
    Child,
    ConfigError,
    Extension,
    Parser,
    Table,
    accepted,
    header,
    table_of,
    toml_value,
)

EMBEDDED_SOURCE: Final = "<embedded default>"
"""`Config.source` of the embedded default configuration."""

EMBEDDED_WORLD: Final = """\
[dc]
[[motors]]
name = "x"
[[motors]]
name = "y"
[[motors]]
name = "z"
[[pins]]
number = 0
[[pins]]
number = 1
[[pins]]
number = 2
[[pins]]
number = 3
[[pins]]
number = 4
mode = "input"
[[pins]]
number = 5
mode = "input"
[[pins]]
number = 6
mode = "input"
[[pins]]
number = 7
mode = "input"
[mock]
"""
"""The embedded default world: three linear motors x, y, z, a DC motor, output pins 0-3 and
input pins 4-7 wired to them by the [mock] default. Every other key takes its declared
default; `default_config_text()` writes them all out."""

_HEADER: Final = """\
# motorctl: the embedded default configuration.
#
# Used when motorctld is started without a config file. It describes a simulated ("mock")
# world in which every protocol command can be tried: three linear motors x, y and z, a DC
# motor, output pins 0-3 wired to input pins 4-7. Every key is written out with its default
# value and what it accepts, so this text doubles as a commented example; docs/config.md is
# the full reference. Check an edited copy with:  motorctld --check-config FILE
"""


def extensions() -> list[Extension]:
    """Every registered backend's config sections."""
    found: list[Extension] = []
    for name, sections in config_sections():
        for ext in sections:
            if not isinstance(ext, Extension):
                raise TypeError(f"backend {name!r}: CONFIG_SECTIONS holds {ext!r}")
            found.append(ext)
    return found


def schema() -> Table:
    """The whole file's schema: the core model plus the backends' sections."""
    return table_of(Config).extended(extensions())


_TOML_POSITION = re.compile(r"\(at line (\d+), column (\d+)\)$")


def parse_config(text: str, source: str) -> Config:
    """Validate TOML `text`; `source` (a path, usually) starts every error message."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        match = _TOML_POSITION.search(message)
        if match is not None:
            line = int(match.group(1))
        else:  # "(at end of document)"
            line = max(1, text.count("\n") + (0 if text.endswith("\n") else 1))
        raise ConfigError(f"{source}: line {line}: TOML syntax error: {message}") from None
    except RecursionError:  # arrays or inline tables nested thousands deep
        raise ConfigError(
            f"{source}: TOML nested too deeply to be read; accepted: a config's tables and "
            "arrays, nested a few levels"
        ) from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        why = str(exc).split(":")[0]  # without the advice to raise Python's own limit
        raise ConfigError(f"{source}: TOML that cannot be read ({why})") from None
    parser = Parser(source)
    config = parser.build(schema(), document, source=source)
    assert isinstance(config, Config)
    return dataclasses.replace(config, notices=tuple(parser.notices)) if parser.notices else config


class _NotRegular(OSError):
    """The config path names something other than a regular file (what, in the message)."""


def _read_regular(source: str) -> bytes:
    """The bytes of the regular file at ``source`` (a link to one is followed: a config is
    only read). A FIFO, a device, a socket or a directory is never read from, never waited
    for: _NotRegular. OSError as ``open`` raises it."""
    mode = os.stat(source).st_mode  # a device is not even opened
    if not stat.S_ISREG(mode):
        raise _NotRegular(errno.EINVAL, kind(mode))
    fd = os.open(source, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise _NotRegular(errno.EINVAL, kind(mode))
        chunks = []
        while chunk := os.read(fd, 1 << 16):
            chunks.append(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def load_config(path: str | os.PathLike[str] | None) -> Config:
    """Read and validate the config file at `path`; None loads the embedded default."""
    if path is None:
        return parse_config(EMBEDDED_WORLD, EMBEDDED_SOURCE)
    source = os.fspath(path)
    try:
        data = _read_regular(source)
    except FileNotFoundError:
        raise ConfigError(
            f"{source}: config file not found; fix: create it (`motorctld "
            "--print-default-config` prints a commented example; docs/config.md describes "
            "every key) or give the path of an existing file"
        ) from None
    except _NotRegular as exc:
        raise ConfigError(
            f"{source}: is {exc.strerror}, not a regular file; fix: give the path of a TOML file"
        ) from None
    except OSError as exc:
        raise ConfigError(
            f"{source}: cannot read config file: {exc.strerror}; "
            "fix: give the path of a readable TOML file"
        ) from None
    if data.startswith(codecs.BOM_UTF8):  # written by some editors: not part of the TOML
        data = data[len(codecs.BOM_UTF8) :]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{source}: line {line}: not valid UTF-8; accepted: a UTF-8 encoded TOML file"
        ) from None
    return parse_config(text, source)


# --------------------------------------------------------------------------------------------
# Writing a config out as commented TOML


def default_config_text() -> str:
    """The embedded default configuration, every key written out with its doc."""
    return _HEADER + "\n" + to_toml(load_config(None))


def to_toml(config: Config) -> str:
    """`config` as a TOML file that loads back to it, every key written out and documented."""
    out: list[str] = []
    _write_table(schema(), config, "", True, out)
    return "\n".join(out).strip("\n") + "\n"


def _comment(text: str) -> list[str]:
    return ["# " + line for line in textwrap.wrap(text, 96)]


def _write_table(spec: Table, value: Any, path: str, documented: bool, out: list[str]) -> None:
    for key in spec.keys:
        v = getattr(value, key.name)
        if documented:
            out.extend(_comment(f"{key.doc} Accepted: {accepted(key)}."))
        if v is None:
            out.append(f"# {key.name} = (unset)")
        else:
            out.append(f"{key.name} = {toml_value(v, limit=1 << 20)}")
    for child in spec.children:
        _write_child(spec, child, value, path, documented, out)


def _write_child(
    parent: Table, child: Child, value: Any, path: str, documented: bool, out: list[str]
) -> None:
    sub = f"{path}.{child.name}" if path else child.name
    where = header(sub, child.array)
    v = value.sections[child.table.cls] if child.extension else getattr(value, child.name)
    if v is None:
        out += ["", f"# {where}: left out ({child.absent_text}). {child.table.doc}"]
        return
    if not child.array:
        out += ["", f"{where}", *(_comment(child.table.doc) if documented else [])]
        _write_table(child.table, v, sub, documented, out)
        return
    for i, item in enumerate(v):
        first = documented and i == 0
        note = child.table.doc if first else f"{child.name}[{i}]: keys as documented above"
        out += ["", where, *_comment(note)]
        _write_table(child.table, item, sub, first, out)
