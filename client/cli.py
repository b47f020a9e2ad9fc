"""``motorctl``: send one protocol command to a motorctl device and print the answer.

Its commands are the command table's (motorctl.protocol.commands): each command's words, its
arguments (each parameter's range, unit and default, positional or an option) and the line
printed for its answer come from there; ``tap``, ``trace``, ``replay``, ``monitor`` and
``send`` are the tool's own."""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import sys
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import serial

from motorctl import __version__
from motorctl.client import reasons, replay, tap, trace
from motorctl.client.client import Client, DeviceError, LinkError, hex_bytes
from motorctl.client.port_errors import not_a_port, open_error
from motorctl.protocol.codec import (
    COMMANDS,
    FRAME_LEN,
    CodecOptions,
    Command,
    FrameError,
    decode_command,
)
from motorctl.protocol.crc import CHECKSUM_DEFAULT, CHECKSUM_TEXT, checksum_by_name
from motorctl.protocol.spec import Param, Spec

__all__ = ["build_parser", "main"]


_UNITS = f"""\
All numbers are the raw protocol values the host sends, not physical units: each command's
--help gives each value's range, and its unit with the protocol's default factor (a daemon's
[units] may set others); a speed, ACC or DEC of 0 means the motor's configured default.
Integers may be given in decimal or with a 0x/0o/0b prefix.

An error answer is printed with its reason: the daemon's, when its status socket is
readable from here (beside the port, in .run/state beside it, in /run/motorctl, or in
${reasons.STATE_DIR_ENV}; docs/status.md), e.g. "error: E2 invalid address: no motor 5
(this machine has motors 0..2)", else what the code means for that command ("error: E2
invalid address: no motor 5").

exit status: 0 ok, 1 the device answered with an error, 2 usage error or link error
(no/short/corrupt response), 130 interrupted (Ctrl-C)."""


def _int_in(lo: int, hi: int, what: str) -> Callable[[str], int]:
    """argparse type: an integer in [lo, hi] (decimal or 0x/0o/0b)."""

    def parse(text: str) -> int:
        text = text.strip()
        try:
            value = int(text, 0)
        except ValueError:
            try:
                value = int(text, 10)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{what}: {text!r} is not an integer") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{what}: {value} is not in {lo}..{hi}")
        return value

    parse.__name__ = what
    return parse


#: the longest response timeout (a day): pyserial's waits cannot take ``inf`` or 1e300 s
MAX_TIMEOUT_S = 86400.0


def _seconds(text: str) -> float:
    """argparse type: a positive number of seconds, at most MAX_TIMEOUT_S."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"timeout must be positive, got {text.strip()}")
    if not value <= MAX_TIMEOUT_S:
        raise argparse.ArgumentTypeError(
            f"timeout must be at most {MAX_TIMEOUT_S:g} s (a day), got {text.strip()}"
        )
    return value


def _choice(mapping: dict[str, bool], what: str) -> Callable[[str], bool]:
    """argparse type: one of the words in ``mapping`` (case-insensitive)."""

    def parse(text: str) -> bool:
        try:
            return mapping[text.lower()]
        except KeyError:
            words = ", ".join(mapping)
            raise argparse.ArgumentTypeError(f"{what}: {text!r} is not one of {words}") from None

    parse.__name__ = what
    return parse


def _said(text: str) -> str:
    """A command's summary as a help line ends: a question keeps its mark."""
    return text if text.endswith("?") else f"{text}."


def param_help(p: Param) -> str:
    """An argument's help: what it is, its range and unit, its default (the table's)."""
    text = p.help
    if p.wire != "bool":
        text += f"; {p.range_text()}"
    if p.default is not None and p.option and p.wire != "bool" and p.default != 0:
        text += f"; default {p.default}"
    elif p.default is not None and (p.words is not None or not p.option):
        text += f"; default {p.typed(p.default)}"
    return text


def _add_param(parser: argparse.ArgumentParser, p: Param) -> None:
    """One parameter of the command table as an argument (see :class:`Param`)."""
    what = p.label.lower()
    if p.wire == "bool" and p.words is None:  # a flag, maybe with its opposite
        if not p.option:
            raise ValueError(f"{p.name}: a boolean without words must be an option")
        if p.off_option:
            group = parser.add_mutually_exclusive_group()
            group.add_argument(
                p.off_option, dest=p.name, action="store_false", default=p.default, help=p.off_help
            )
            group.add_argument(p.option, dest=p.name, action="store_true", help=param_help(p))
        else:
            parser.add_argument(p.option, dest=p.name, action="store_true", help=param_help(p))
        return
    kind: Callable[[str], int] | Callable[[str], bool]
    if p.wire == "bool":
        kind, metavar = _choice(p.choices(), what), p.placeholder
    else:
        kind, metavar = _int_in(p.lo, p.hi, what), p.placeholder
    if p.option:
        parser.add_argument(
            p.option, dest=p.name, type=kind, default=p.default, metavar=metavar, help=param_help(p)
        )
    elif p.default is not None:
        parser.add_argument(
            p.name, type=kind, nargs="?", default=p.default, metavar=metavar, help=param_help(p)
        )
    else:
        parser.add_argument(p.name, type=kind, metavar=metavar, help=param_help(p))


def _errors(spec: Spec) -> str:
    """The errors a command can give, in the contract's precedence, with what each means."""
    names = {p.name: p.placeholder for p in spec.params}
    lines = [f"  {g.code.short} {g.means.format_map(names)}" for g in spec.gives]
    lines.append("  (and for any frame: E1 when it fails its checksum, code or padding)")
    return "errors it can give (PROTOCOL.md section 5, first wins):\n" + "\n".join(lines)


def _add_commands(sub: Any, add: Callable[..., argparse.ArgumentParser]) -> None:
    """The command table's commands: one subcommand each, by its words (``pin set``: a
    group of commands under its first word)."""
    groups: dict[str, Any] = {}
    for cls in COMMANDS:
        spec = cls.spec
        help_text = f"{spec.name}: {spec.summary[0].lower()}{spec.summary[1:]}"
        if len(spec.cli) == 1:
            p = add(sub, spec.cli[0], help_text, _errors(spec))
        elif len(spec.cli) == 2:
            word, action = spec.cli
            if word not in groups:
                names = " / ".join(c.spec.name for c in COMMANDS if c.spec.cli[:1] == (word,))
                group = add(sub, word, names)
                groups[word] = group.add_subparsers(
                    dest=f"{word}_command", metavar="ACTION", required=True
                )
            p = add(groups[word], action, help_text, _errors(spec))
        else:
            raise ValueError(f"{spec.name}: command-line words {spec.cli} (one or two)")
        p.set_defaults(table_command=cls)
        for param in spec.params:
            _add_param(p, param)


def build_parser() -> argparse.ArgumentParser:
    """Build the ``motorctl`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="motorctl",
        description="Send one command to a motorctl device and print the answer.",
        epilog=_UNITS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"motorctl {__version__}")
    parser.add_argument(
        "-p",
        "--port",
        metavar="PATH",
        default=os.environ.get("MOTORCTL_PORT"),
        help="serial port (default: $MOTORCTL_PORT)",
    )
    parser.add_argument(
        "--baud",
        type=tap.baud_rate,
        default=115200,
        help="baud rate (default 115200; any whole number of baud the port's driver can "
        "make; a PTY ignores it)",
    )
    parser.add_argument(
        "--timeout",
        type=_seconds,
        default=5.0,
        metavar="SECONDS",
        help="response timeout in seconds (default 5, at most 86400; wait adds its TIMEOUT_MS)",
    )
    parser.add_argument(
        "--checksum",
        default=CHECKSUM_DEFAULT,
        metavar="NAME",
        help=f"{CHECKSUM_TEXT}; default {CHECKSUM_DEFAULT}",
    )
    parser.add_argument(
        "--crc-covers-ack", action="store_true", help="the response CRC covers R0..R3"
    )
    parser.add_argument(
        "--raw", action="store_true", help="print the bytes sent (->) and received (<-) as hex"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(where: Any, name: str, help_text: str, epilog: str = "") -> argparse.ArgumentParser:
        return where.add_parser(  # type: ignore[no-any-return]
            name,
            help=help_text,
            description=textwrap.fill(
                f"{_said(help_text)} Numbers are the protocol's raw values (motorctl --help).",
                width=80,
            ),
            epilog=epilog or None,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )

    _add_commands(sub, add)

    tap.add_parser(sub)
    replay.add_parser(sub)
    trace.add_parser(sub)
    p = sub.add_parser(
        "monitor",
        help="live view of a motorctld on this machine (its status socket)",
        description="A live view of the daemon on this machine, refreshing in the terminal "
        "(also over SSH): each motor's position, state, speed and fault, step timing, pins "
        "and the DC motor, link counters, frames/s and the last frames, the executor's "
        "health. Reads the status socket (docs/status.md), not the serial port; the same "
        "as 'motorctld --status --watch'. Needs the Python package rich (Debian: "
        "python3-rich; pip: motorctl[monitor]). Ctrl-C quits.",
    )
    p.add_argument(
        "--state-dir",
        type=Path,
        default=Path("/run/motorctl"),
        help="the daemon's --state-dir, where status.sock is (default /run/motorctl)",
    )
    p.add_argument(
        "--period",
        type=int,
        default=250,
        metavar="MS",
        help="how often the daemon looks for a change (20..60000 ms, default 250)",
    )
    p.add_argument(
        "--once", action="store_true", help="print the view once and exit (scripts, logs)"
    )

    p = add(sub, "send", "send an arbitrary frame given as hex and print the decoded response")
    p.add_argument(
        "hex",
        nargs="+",
        metavar="HEX",
        help="9 bytes (checksum appended) or 10 bytes (sent as is), "
        'e.g. "03 00 00 00 00 00 00 00 00" or 030000000000000000',
    )
    return parser


_NEGATIVE = re.compile(r"-\d")


def _protect_negatives(argv: Sequence[str]) -> list[str]:
    """Let negative numbers through argparse as positionals.

    argparse reads "-0x10" (and, if an option ever looks numeric, "-500") as an option. An
    argument that does not start with "-" is never an option, so prefix a space; the
    integer parsers strip it.
    """
    return [" " + arg if _NEGATIVE.match(arg) else arg for arg in argv]


def _parse_hex(words: Sequence[str]) -> bytes:
    text = "".join(w.replace("0x", "").replace("0X", "").replace(":", "") for w in words)
    text = "".join(text.split())
    try:
        return bytes.fromhex(text)
    except ValueError:
        raise ValueError(f"not hex bytes: {' '.join(words)!r}") from None


def _send(client: Client, frame: bytes) -> str:
    """Send an arbitrary frame; return "ok, payload ..." or raise DeviceError."""
    client.send_frame(frame)
    resp = client.read_response()
    if not resp.ack:
        code = resp.error_code
        raise DeviceError(code if code is not None else resp.payload[0])
    return f"ok, payload {hex_bytes(resp.payload)}"


def _run(client: Client, args: argparse.Namespace) -> str:
    """Execute the subcommand (a command of the table); return the line to print."""
    cls: type[Command] = args.table_command
    spec = cls.spec
    values = {p.name: getattr(args, p.name) for p in spec.params}
    reading = client.call(cls(**values))
    return spec.answer.line.format(**values, value=reading.value, text=reading.text)


def _why(exc: DeviceError, client: Client, options: CodecOptions, port: str) -> str:
    """An error answer with its reason (client/reasons.py): the daemon's, or the code's
    meaning for the command (a frame sent as hex: its command, if it is one)."""
    command: Command | None = exc.command
    frame: bytes | None = None
    if command is None:
        frame = client.last_request
        with contextlib.suppress(FrameError):  # a frame that is no command: its bytes
            command = decode_command(frame, options)
    return reasons.explain(exc.code, command, port, client.sent_at, frame)


def _interrupted(args: argparse.Namespace) -> str:
    """Ctrl-C: for a WaitMoved, the motor does not stop with the command."""
    cls = getattr(args, "table_command", None)
    if cls is not None and cls.spec.answer.held:  # the wait ends, not the motion
        n = args.motor
        return (
            f"interrupted: motor {n} keeps moving (only the wait ended); stop it with "
            f"'motorctl stop {n}' ('--hard' for at once)"
        )
    return "interrupted"


def _print_raw(client: Client) -> None:
    if client.last_request:
        print(f"-> {hex_bytes(client.last_request)}")
    if client.last_response:
        print(f"<- {hex_bytes(client.last_response)}")


EXIT_PIPE = 128 + 13  # as a program killed by SIGPIPE: what `cat FILE | head` gives cat


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``motorctl`` console script; returns the exit status. Output into
    a pipe whose reader went away (``motorctl trace FILE | head``) ends the command quietly,
    as it ends ``cat``."""
    try:
        return _main(argv)
    except BrokenPipeError:
        # Python would flush stdout again at exit and complain: point it at /dev/null
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_PIPE


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(_protect_negatives(sys.argv[1:] if argv is None else argv))
    if args.command == "trace":
        return trace.run(args)
    if args.command == "tap":
        return tap.run(args)
    if args.command == "replay":
        return replay.run(args)
    if args.command == "monitor":
        # The status socket is the daemon's own interface: its reader and view live there.
        from motorctl.daemon.status import monitor

        return monitor.run(args.state_dir / "status.sock", args.period, args.once)
    if not args.port:
        parser.error("no serial port: pass -p PATH or set MOTORCTL_PORT")
    try:
        crc = checksum_by_name(args.checksum)
    except ValueError as exc:
        parser.error(f"--checksum: {exc}")
    options = CodecOptions(crc=crc, crc_covers_ack=args.crc_covers_ack)

    frame: bytes | None = None
    if args.command == "send":
        try:
            data = _parse_hex(args.hex)
        except ValueError as exc:
            parser.error(f"send: {exc}")
        if len(data) == FRAME_LEN - 1:
            frame = data + bytes([crc.compute(data) if crc is not None else 0])
        elif len(data) == FRAME_LEN:
            frame = data
        else:
            parser.error(f"send: need {FRAME_LEN - 1} or {FRAME_LEN} bytes, got {len(data)}")

    problem = not_a_port(args.port)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        client = Client(args.port, args.baud, args.timeout, options)
    except (serial.SerialException, OSError, ValueError) as exc:
        print(f"error: {open_error(args.port, exc, args.baud)}", file=sys.stderr)
        return 2
    with client:
        try:
            line = _send(client, frame) if frame is not None else _run(client, args)
            status = 0
        except DeviceError as exc:
            line, status = f"error: {_why(exc, client, options, args.port)}", 1
        except LinkError as exc:
            line, status = f"error: {exc}", 2
        except ValueError as exc:  # a field the codec refuses
            line, status = f"error: {exc}", 2
        except KeyboardInterrupt:
            line, status = _interrupted(args), 130
        if args.raw:
            _print_raw(client)
        sys.stdout.flush()
        print(line, file=sys.stdout if status == 0 else sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
