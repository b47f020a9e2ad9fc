"""``motorctl``: send one protocol command to a motorctl device and print the answer."""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import serial

from motorctl import __version__
from motorctl.client import reasons, replay, tap, trace
from motorctl.client.client import Client, DeviceError, LinkError, hex_bytes
from motorctl.client.port_errors import not_a_port, open_error
from motorctl.protocol.codec import (
    FRAME_LEN,
    POS_MAX,
    POS_MIN,
    CodecOptions,
    Command,
    FrameError,
    decode_command,
)
from motorctl.protocol.crc import CHECKSUM_DEFAULT, CHECKSUM_TEXT, checksum_by_name

__all__ = ["build_parser", "main"]


_UNITS = f"""\
All numbers are the raw protocol values the host sends, not physical units: MOTOR, PIN,
waypoint N and --speed/--acc/--dec are single bytes (0..255; 0 = the motor's configured
default); with the default factors InitMove/Move speed = SPEED x 4096 step/s, MoveTo and
waypoint speed = SPEED x 4 step/s, ramps = ACC/DEC x 16 step/s^2. POS is a signed 24-bit
step count ({POS_MIN}..{POS_MAX}). Times are milliseconds (0..65535). Integers may be given
in decimal or with a 0x/0o/0b prefix.

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


_byte = _int_in(0, 255, "byte")
_u16 = _int_in(0, 0xFFFF, "milliseconds")
_pos = _int_in(POS_MIN, POS_MAX, "position")


def _seconds(text: str) -> float:
    """argparse type: a positive number of seconds."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"timeout must be positive, got {text.strip()}")
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


_updown = _choice({"up": True, "down": False}, "direction")
_highlow = _choice({"high": True, "low": False}, "level")
_inout = _choice({"in": False, "input": False, "out": True, "output": True}, "pin mode")


_MOTOR = "motor number: 0 is the first motor of the daemon's config"
_PIN = "pin number, as the daemon's config numbers its IO pins"


def _add_ramp(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speed", type=_byte, default=0, metavar="N", help="SPEED byte (0=default)")
    p.add_argument("--acc", type=_byte, default=0, metavar="N", help="ACC byte (0=default)")
    p.add_argument("--dec", type=_byte, default=0, metavar="N", help="DEC byte (0=default)")


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
        help="response timeout in seconds (default 5; wait adds its TIMEOUT_MS)",
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

    def add(name: str, help_text: str) -> argparse.ArgumentParser:
        return sub.add_parser(
            name,
            help=help_text,
            description=f"{help_text.rstrip('?.')}{'?' if help_text.endswith('?') else '.'} "
            "Numbers are the protocol's raw values (motorctl --help).",
        )

    p = add("init", "InitMove: home MOTOR towards its end stop (position becomes 0)")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    p.add_argument(
        "direction",
        type=_updown,
        metavar="up|down",
        help="where its end stop is: up (counting up) or down",
    )
    _add_ramp(p)

    p = add("moveto", "MoveTo: queue a move of MOTOR to the absolute step position POS")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    p.add_argument(
        "position",
        type=_pos,
        metavar="POS",
        help=f"absolute target in steps, {POS_MIN}..{POS_MAX}",
    )
    _add_ramp(p)
    p.add_argument(
        "--dir",
        dest="direction",
        type=_updown,
        default=True,
        metavar="up|down",
        help="DIR byte (used on rotary axes only; default up)",
    )

    p = add("wait", "WaitMoved: wait until MOTOR is idle (E3 after TIMEOUT_MS)")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    p.add_argument(
        "timeout_ms",
        type=_u16,
        nargs="?",
        default=60000,
        metavar="TIMEOUT_MS",
        help="device-side timeout in ms (default 60000)",
    )

    p = add("ready", "IsReady: is MOTOR idle with an empty queue?")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)

    p = add("move", "Move: run MOTOR continuously until stopped")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    p.add_argument("direction", type=_updown, metavar="up|down", help="up (counting up) or down")
    _add_ramp(p)

    p = add("stop", "StopMove: stop MOTOR and empty its queue")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    p.add_argument("--hard", action="store_true", help="stop without a ramp")

    p = add("pos", "GetAbsPos: print the position of MOTOR")
    p.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)

    p = add("pin", "SetPin / GetPin / ConfigPin")
    pin_sub = p.add_subparsers(dest="pin_command", metavar="ACTION", required=True)
    q = pin_sub.add_parser("set", help="drive output PIN high or low")
    q.add_argument("pin", type=_byte, metavar="PIN", help=_PIN)
    q.add_argument("level", type=_highlow, metavar="high|low", help="the level to drive")
    q = pin_sub.add_parser("get", help="read PIN")
    q.add_argument("pin", type=_byte, metavar="PIN", help=_PIN)
    q = pin_sub.add_parser("config", help="make PIN an input or an output")
    q.add_argument("pin", type=_byte, metavar="PIN", help=_PIN)
    q.add_argument("output", type=_inout, metavar="in|out", help="in: an input, out: an output")

    p = add("home", "SaveHome / GoHome")
    home_sub = p.add_subparsers(dest="home_command", metavar="ACTION", required=True)
    q = home_sub.add_parser("save", help="store the current position of MOTOR as home")
    q.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    q = home_sub.add_parser("go", help="queue a move of MOTOR to its home")
    q.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)

    p = add("waypoint", "SaveWayPoint / MoveToWayPoint")
    wp_sub = p.add_subparsers(dest="waypoint_command", metavar="ACTION", required=True)
    q = wp_sub.add_parser("save", help="store the current position of MOTOR as a waypoint")
    q.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    q = wp_sub.add_parser("go", help="queue a move of MOTOR to waypoint N")
    q.add_argument("motor", type=_byte, metavar="MOTOR", help=_MOTOR)
    q.add_argument(
        "waypoint", type=_byte, metavar="N", help="waypoint number, as SaveWayPoint gave it"
    )
    _add_ramp(q)

    p = add("dc", "DcMove: run the DC motor TIME_MS, then brake (default) or coast")
    p.add_argument(
        "direction",
        type=_choice({"forward": True, "reverse": False}, "direction"),
        metavar="forward|reverse",
        help="the DC motor's direction",
    )
    p.add_argument("time_ms", type=_u16, metavar="TIME_MS", help="run time in ms (0 = stop)")
    end = p.add_mutually_exclusive_group()
    end.add_argument(
        "--brake",
        dest="hiz",
        action="store_false",
        default=False,
        help="end with the bridge braking (GO_HiZ FALSE, default)",
    )
    end.add_argument(
        "--hiz",
        dest="hiz",
        action="store_true",
        help="end with the bridge in high impedance (GO_HiZ TRUE, coasting)",
    )

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

    p = add("send", "send an arbitrary frame given as hex and print the decoded response")
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
    """Execute the subcommand; return the line to print."""
    cmd: str = args.command
    if cmd == "init":
        client.init_move(args.motor, args.direction, args.speed, args.acc, args.dec)
    elif cmd == "moveto":
        client.move_to(args.motor, args.position, args.speed, args.acc, args.dec, args.direction)
    elif cmd == "wait":
        client.wait_moved(args.motor, args.timeout_ms)
    elif cmd == "ready":
        state = "ready" if client.is_ready(args.motor) else "busy"
        return f"motor {args.motor} {state}"
    elif cmd == "move":
        client.move(args.motor, args.direction, args.speed, args.acc, args.dec)
    elif cmd == "stop":
        client.stop(args.motor, args.hard)
    elif cmd == "pos":
        return f"motor {args.motor} at {client.position(args.motor)}"
    elif cmd == "pin":
        if args.pin_command == "set":
            client.set_pin(args.pin, args.level)
        elif args.pin_command == "get":
            return f"pin {args.pin} {'high' if client.get_pin(args.pin) else 'low'}"
        else:
            client.config_pin(args.pin, args.output)
    elif cmd == "home":
        if args.home_command == "save":
            client.save_home(args.motor)
        else:
            client.go_home(args.motor)
    elif cmd == "waypoint":
        if args.waypoint_command == "save":
            number = client.save_waypoint(args.motor)
            return f"waypoint {number} saved on motor {args.motor}"
        client.move_to_waypoint(args.motor, args.waypoint, args.speed, args.acc, args.dec)
    elif cmd == "dc":
        client.dc_move(args.direction, args.time_ms, args.hiz)
    else:  # pragma: no cover - argparse only yields the commands above
        raise AssertionError(cmd)
    return "ok"


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
    if args.command == "wait":
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
