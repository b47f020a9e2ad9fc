"""docs/config.md, generated from the schema: `python -m motorctl.daemon.config.docs --write`.

The page is the prose below plus, for every table, its rows (`motorctl.schema.describe`) and
the prose its `@section` declares. tests/daemon/test_config.py checks that docs/config.md equals
`render()`, so a new or changed key fails the tests until the page is regenerated.

Pure: `render()` reads only the schema; `main()` writes or checks the file.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Final

from motorctl.daemon.config.loader import schema
from motorctl.protocol.crc import ALIASES, checksum_names
from motorctl.schema import Child, Row, Table, describe_child, header

WIDTH: Final = 92

DOCS: Final = Path(__file__).resolve().parents[2] / "docs" / "config.md"
"""docs/config.md of a checkout (this file is daemon/config/docs.py)."""

INTRO: Final = """\
# motorctl configuration reference

motorctld reads **one TOML file**. Every key has a type, a default and bounds; a key
that is not listed here is an error, not silently ignored (the same model as Klipper's
config reader). Leave a key out to get its default; leave a whole table out to get all of
its defaults (the exceptions are `[dc]`, `[[pins]]`, `[mock]` and `[[motors]]`, see below).

The file is given with `motorctld --config FILE`. Without `--config` the daemon uses the
**embedded default**: a simulated ("mock") world with three motors `x`, `y`, `z`, a DC
motor, output pins 0-3 and input pins 4-7, each output wired to the input four above it
(`EMBEDDED_WORLD` in `daemon/config/loader.py`; every other key at its default).
`motorctld --print-default-config` writes it out with every key, its value and what it
accepts, so it is the best starting point for your own file:
`motorctld --print-default-config > motorctl.toml`.

## Checking a file

```
motorctld --check-config /etc/motorctl.toml
```

loads the file exactly as the daemon would at start-up (`load_config`) and prints a line
with `OK` and a short summary (exit status 0), or the error (exit status 1).

The file is UTF-8 text; a UTF-8 byte order mark at its top (which some editors write) is
accepted and ignored. The path must name a regular file (a symbolic link to one is fine):
a FIFO, a device, a socket or a directory is refused at once, never read from or waited
for (`/etc/motorctl.toml: is a FIFO, not a regular file; fix: give the path of a TOML
file`), so that `ExecStartPre=motorctld --check-config` cannot hang a unit's start.

## How errors look

Loading stops at the first problem. The message names the file, the key path (arrays of
tables by index, counting from 0: `motors[1]` is the second `[[motors]]` table), the value
found, the problem, and what is accepted:

```
/etc/motorctl.toml: motors[1].max_speed = 0: out of range; accepted: a number > 0 and <= 200000
/etc/motorctl.toml: link.held_frames = true: wrong type (boolean); accepted: an integer in 1..1024
/etc/motorctl.toml: unknown key 'link.frame_gap'; accepted keys in [link]: checksum, crc_covers_ack, frame_gap_ms, held_frames, strict_padding
/etc/motorctl.toml: motors[0].soft_limit_min = -500: soft_limit_max is not set; accepted: set both soft_limit_min and soft_limit_max, or neither
/etc/motorctl.toml: mock.wires[1] = [1, 2]: pin 2 is not in [[pins]] (configured pins: 0, 1); accepted: every wired pin is listed in [[pins]]
/etc/motorctl.toml: hal.backend = "gpio": unknown value; accepted: one of "mock", "gpiod" (the backends of motorctl.hal.registry)
/etc/motorctl.toml: motors: missing; accepted: 1..64 [[motors]] tables (a config needs at least one)
/etc/motorctl.toml: line 3: TOML syntax error: Invalid value (at line 3, column 12)
/etc/motorctl.toml: config file not found; fix: create it (`motorctld --print-default-config` prints a commented example; docs/config.md describes every key) or give the path of an existing file
```

A bound may name another key; the error then shows its value. When a default breaks such
a rule (say `max_speed = 1000` leaves `default_speed` at its default 2000), the message
says so:

```
/etc/motorctl.toml: motors[0].default_speed = 2000.0: out of range (the default value; set the key explicitly); accepted: a number > 0 and <= max_speed (max_speed = 1000)
```

## Types

| type | what to write |
|---|---|
| integer | a TOML integer: `16`. `16.0` and `true` are refused (a boolean is not an integer). |
| number | a TOML integer or float: `2000`, `2000.0`, `2.5e3`. `nan` and `inf` are out of range. |
| boolean | `true` or `false` |
| string | a TOML string: `"crc8"` |
| integer (optional) | an integer, or leave the key out (there is no TOML null) |
| array of [pin, pin] | `[[0, 4], [1, 5]]` |

"a number in A..B" includes both ends; "> A" excludes A.

## A minimal file

```toml
[[motors]]
name = "x"
```

One linear motor, every other key at its default: no DC motor, no pins, no wires, mock
backend, CRC-8/SMBUS checksums.

## Keys of earlier releases

A key that an earlier release had and this one no longer reads is *retired*, not unknown:
a file that writes it still loads, the value is ignored, and a warning names the key, why
and what to write instead (`motorctld --check-config` prints it; the daemon logs it at
start). A warning rather than an error, so that a daemon upgraded in place starts with the
file it had (one written by `--print-default-config` writes every key), while its owner
learns what changed; the reference below lists each retired key under its table. So
`[step_thread] driver_poll_ms` and `[motors.tmc] poll_ms`, the periods of the two pollers
a driver fault used to pass through, load with a warning that names the one poller's
period that replaced them, `[drivers] poll_ms`:

```
warning: /etc/motorctl.toml: 'step_thread.driver_poll_ms' is retired and ignored: the HAL's one driver poller reads every driver chip now and hands a fault to the motors as it reads it, with nothing to do with the step thread; its period is [drivers] poll_ms; fix: remove it
```
"""

HOW_TO: Final = """\
## Adding configuration

Every key is declared once, next to the code that owns it: a field of a frozen dataclass
made a table by `@section` (`motorctl/schema/fields.py`). The field's helper (`integer`, `number`,
`boolean`, `choice`, `text`, `pairs`, `table`, `tables`) holds the default, the bounds and
the doc; the same dataclass is what the code reads. This page, the checks and
`--print-default-config` are all generated from those declarations.

- **A key in an existing table**: add one field to the table's dataclass
  (`daemon/config/model.py` for the core tables, `hal/backends/<backend>/config.py` for a
  backend's), then run `python -m motorctl.daemon.config.docs --write`.
- **A core table** (say `[executor]` with `kind = "process"` or `"thread"`, or `[state]`):
  declare a `@section` dataclass in `daemon/config/model.py`, add one field
  `executor: ExecutorConfig = table(ExecutorConfig)` to `Config`, regenerate this page. Use
  `choice(default, SomeStrEnum, doc)` for a fixed set of names: the code then gets the enum.
  The dataclass may live with the code that owns it (an executor's table in `motion/`, which
  may import `motorctl.schema` but not the daemon); only the `Config` field is in model.py.
  `[step_thread]` is one: `motion/executors/config.py`.
- **A default that code outside the config needs too** (a record's field, a parameter's
  default): write the value once. Either the record (or a constant beside it) holds it and
  the key's helper reads it (`number(TmcSettings.run_current, ...)`,
  `integer(PwmWiring.period_ns, ...)`, `SPIN_S` shown in microseconds), or the record reads
  the key's (`default_of(LinkConfig, "held_frames")`). `tests/daemon/test_config_defaults.py`
  reads the source and fails on a default written in two places.
- **A hardware backend's tables** (say `[gpiod]` and `[motors.gpiod]`): declare them in
  `hal/backends/<backend>/config.py`, a module that imports no hardware library, whose
  declaration (a `BackendDeclaration`, `hal/contract.py`) returns them from `sections()`:
  `(Extension("", "gpiod", GpiodConfig, owner=...), Extension("motors", "gpiod",
  GpiodAxisConfig, owner=...))`; name that class as the `declaration` of the backend's
  entry in `hal/registry.py` (a layer's likewise, `hal/layers/<layer>/config.py`). The
  backend's `build(spec, clock)` reads them from the HardwareSpec:
  `spec.section(GpiodConfig)`, `spec.axes[i].section(GpiodAxisConfig)`. Regenerate this
  page.
- A rule across keys (a bound naming another key: `hi="max_speed"`; anything else: a `Rule`
  in `@section(rules=...)`) keeps the error format: file, key, value, problem, accepted.
"""

API: Final = """\
## Python API

`motorctl.daemon.config.load_config(path)` returns a frozen `Config` (`load_config(None)`
loads the embedded default; its `source` is `<embedded default>`), `parse_config(text,
source)` validates a string, and every problem raises `motorctl.daemon.config.ConfigError`.
`Config.link.codec_options()` gives the codec's checksum settings; a backend's section is
read with `config.section(Cls)` or `config.motors[i].section(Cls)`.
"""


def _row(row: Row) -> str:
    path, type_, default, what = (cell.replace("|", "\\|") for cell in row)
    return f"| `{path}` | {type_} | {default} | {what} |"


def _notes(child: Child, path: str, keys: str) -> list[str]:
    """The notes of the tables nested in `child` (at `path`, its keys written `keys`.name),
    each as a paragraph naming its table, and their retired keys."""
    found = []
    for sub in child.table.children:
        sub_path = f"{path}.{sub.name}"
        sub_keys = f"{keys}.{sub.name}" + ("[]" if sub.array else "")
        if sub.table.notes:
            owner = f" ({sub.owner})" if sub.owner else ""
            text = f"`{header(sub_path, sub.array)}`{owner}: " + " ".join(sub.table.notes.split())
            found.append(textwrap.fill(text, WIDTH, break_on_hyphens=False))
        found += _retired(sub.table, sub_keys)
        found += _notes(sub, sub_path, sub_keys)
    return found


def _retired(table: Table, keys: str) -> list[str]:
    """A paragraph for each retired key of `table` (its keys written `keys`.name)."""
    return [
        _fill(
            f"Retired: `{keys}.{name}` (any value) still loads, with a warning, and means "
            f"nothing: {why}."
        )
        for name, why in table.retired
    ]


def _fill(text: str) -> str:
    return textwrap.fill(text, WIDTH, break_on_hyphens=False, break_long_words=False)


def render() -> str:
    """The whole of docs/config.md."""
    top: Table = schema()
    names = ", ".join(f"`{c.name}`" for c in top.children)
    parts = [
        INTRO,
        "## Reference\n",
        "Every key, as the daemon's own schema describes it (generated by\n"
        "`python -m motorctl.daemon.config.docs --write` from the declarations; a test keeps\n"
        "this page equal to its output). Keys inside arrays of tables are written\n"
        "`motors[].name`; in a file that is `name = ...` below a `[[motors]]` line.\n",
        "### Top level\n",
        _fill(f"Only these tables are accepted at the top level: {names}.") + "\n",
    ]
    notes: dict[str, list[str]] = {}
    for rule in top.rules:
        for key in rule.keys:
            notes.setdefault(key, []).append(rule.text)
    for child in top.children:
        owner = f" ({child.owner})" if child.owner else ""
        parts.append(f"### {header(child.name, child.array)}{owner}\n")
        if child.table.prose:
            parts.append(child.table.prose + "\n")
        rows = describe_child(child, "", notes)
        table = ["| key | type | default | accepted values and meaning |", "|---|---|---|---|"]
        parts.append("\n".join(table + [_row(r) for r in rows]) + "\n")
        keys = child.name + ("[]" if child.array else "")
        parts += [paragraph + "\n" for paragraph in _retired(child.table, keys)]
        if child.table.notes:
            names = _fill(checksum_names() + ".")
            aliases = ", ".join(sorted(ALIASES))
            parts.append(child.table.notes.format(crc_names=names, crc_aliases=aliases) + "\n")
        for note in _notes(child, child.name, keys):
            parts.append(note + "\n")
    parts += [HOW_TO, API]
    return "\n".join(parts)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the page, write it to docs/config.md (--write) or check that file (--check)."""
    p = argparse.ArgumentParser(description="Generate docs/config.md from the config schema.")
    p.add_argument("--write", action="store_true", help=f"write {DOCS}")
    p.add_argument("--check", action="store_true", help=f"exit 1 if {DOCS} is out of date")
    args = p.parse_args(argv)
    text = render()
    if args.write:
        DOCS.write_text(text, encoding="utf-8")
    elif args.check:
        if DOCS.read_text(encoding="utf-8") != text:
            print(
                f"{DOCS} is out of date: run python -m motorctl.daemon.config.docs --write",
                file=sys.stderr,
            )
            return 1
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
