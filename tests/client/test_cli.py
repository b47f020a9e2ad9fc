"""motorctl's command line (client/cli.py): its help (every positional explained, the
numbers' epilog once, at the top) and ``--baud``'s rule, as a user sees them: the CLI as a
process. Against a daemon: test_cli_e2e.py; against a scripted peer: test_client.py."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.client.cli import _UNITS, build_parser, main
from tests.support import REPO


def motorctl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "motorctl.client.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
        env={"PATH": "/usr/bin:/bin", "MOTORCTL_PORT": "/dev/null"},
    )


def parsers(
    parser: argparse.ArgumentParser, name: str = "motorctl"
) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """Every parser of the command line, with its command words."""
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for word, sub in action.choices.items():
                yield from parsers(sub, f"{name} {word}")


def test_every_positional_of_every_command_says_what_it_is() -> None:
    missing = [
        f"{name}: {action.metavar or action.dest}"
        for name, parser in parsers(build_parser())
        for action in parser._actions
        if not action.option_strings
        and not isinstance(action, argparse._SubParsersAction)
        and not action.help
    ]
    assert missing == []
    assert len(list(parsers(build_parser()))) > 15  # every command was walked


def test_the_numbers_epilog_is_said_once_at_the_top() -> None:
    first = _UNITS.splitlines()[0]
    top = build_parser().format_help()
    assert first in top
    below = [name for name, p in parsers(build_parser()) if name != "motorctl"]
    assert [n for n in below if first in dict(parsers(build_parser()))[n].format_help()] == []
    out = motorctl("moveto", "--help")
    assert out.returncode == 0 and first not in out.stdout
    assert re.search(
        r"MOTOR +motor number: 0 is the first motor of the daemon's config", out.stdout
    )
    assert "(motorctl --help)" in out.stdout


@pytest.mark.parametrize(
    ("baud", "why"),
    [
        ("0", "0 is not a baud rate (to a serial port it means 'hang up')"),
        ("-5", "-5 is not a baud rate"),
        ("1e5", "'1e5' is not a baud rate"),
    ],
)
def test_a_baud_rate_that_is_none_is_a_usage_error(baud: str, why: str) -> None:
    out = motorctl("--baud", baud, "pos", "0")
    assert out.returncode == 2, out.stderr
    assert f"motorctl: error: argument --baud: {why}; accepted: a whole number" in out.stderr
    assert "Traceback" not in out.stderr


def test_a_non_standard_rate_is_taken() -> None:
    args = build_parser().parse_args(["--baud", "250000", "pos", "0"])
    assert args.baud == 250000


def test_tap_takes_the_same_rates(capsys: pytest.CaptureFixture[str]) -> None:
    ports = ["--host", "a", "--device", "b", "--out", "c"]
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["tap", "--baud", "0", *ports])
    assert exc.value.code == 2
    assert "motorctl tap: error: argument --baud: 0 is not a baud rate" in capsys.readouterr().err
    assert build_parser().parse_args(["tap", "--baud", "250000", *ports]).baud == 250000


def test_a_tap_that_cannot_open_a_port_leaves_the_recording_it_would_write_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``motorctl tap --out session.pcapng`` with a port mistyped: the recording made
    before (of the old microcontroller, perhaps) was truncated before the port failed.
    The ports are opened first now; one that is no serial device is said as such."""
    out = tmp_path / "session.pcapng"
    out.write_bytes(b"the old microcontroller's session")
    typo = tmp_path / "notes.txt"
    typo.write_text("")
    missing = tmp_path / "ttyNOPE"
    for host, says in (
        (typo, f"error: the host port {typo}: not a serial device (a regular file)\n"),
        (missing, f"error: cannot open the host port {missing}: "),
    ):
        args = ["tap", "--host", str(host), "--device", str(host), "--out", str(out)]
        assert main(args) == 2
        assert capsys.readouterr().err.startswith(says)
        assert out.read_bytes() == b"the old microcontroller's session"
