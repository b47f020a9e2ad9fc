"""Why the device said no: the daemon's own reason, or the code's meaning for the command.

The wire carries only an error code (E0..E6). motorctld keeps the last error it answered for
each motor and for the link with its reason in words and the commands that fix it
(docs/status.md, ``errors`` and ``motors[].last_error``). On the daemon's machine
:func:`explain` reads them from its status socket and prints

    E4 motor error: end stop hit at -10000 outside homing (motor 0) — clear it with
    'motorctl stop 0'

else the code's meaning for the command that got it (:func:`meaning`: E2 on DcMove is
"no DC motor configured", on MoveTo "no motor 5").

Where the status socket is (the daemon's ``--state-dir``): ``$MOTORCTL_STATE_DIR`` when set,
else the first of these that answers for this very error: beside the port
(``/run/motorctl/motorctl.pty`` and ``/run/motorctl/status.sock``, the packaged service and
its instances), in ``.run/state`` beside it (``make run``: ``./motorctl.pty``,
``./.run/state``), and the default ``/run/motorctl``. A record is this error's only when its
code, command (the same words, :func:`motorctl.protocol.codec.describe`) and time (after the
command was sent, on the machine's monotonic clock) match; anything else, a socket that is
missing, refuses, is slow (at most :data:`STATUS_TIMEOUT_S` in all) or answers nonsense,
gives the code's meaning instead. The socket's protocol is the daemon's (docs/status.md,
"The protocol"): a line, then one JSON document, then the daemon closes.

Threads: the caller's; bounded by ``STATUS_TIMEOUT_S``; no exception escapes.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from motorctl.protocol.codec import BY_NAME, Command, ErrorCode, describe

__all__ = ["STATE_DIR_ENV", "explain", "find_record", "meaning", "socket_paths"]

STATE_DIR_ENV = "MOTORCTL_STATE_DIR"
DEFAULT_STATE_DIR = Path("/run/motorctl")
SOCKET = "status.sock"
#: the longest the reasons may take to read, all sockets together
STATUS_TIMEOUT_S = 1.0
#: a status document is tens of kilobytes; more is not one
MAX_BYTES = 4 << 20

E = ErrorCode


def fix_words(name: str, n: int) -> str | None:
    """What the command ``name`` (a record's or the table's ``fix``) does for motor or pin
    ``n``, on this command line: "clear it with 'motorctl stop 0'" (its remedy and its
    words, from the command table); None for a command that is not a remedy."""
    cls = BY_NAME.get(name)
    if cls is None or not cls.spec.remedy:
        return None
    spec = cls.spec
    given = dict(spec.remedy_args)
    words = ["motorctl", *spec.cli]
    for i, p in enumerate(q for q in spec.params if not q.option):
        if p.name in given:
            words.append(p.typed(given[p.name]))
        elif i == 0:
            words.append(str(n))  # the motor or pin it is about
        else:
            words.append(p.placeholder)
    return f"{spec.remedy} with '{' '.join(words)}'"


def socket_paths(port: str, state_dir: str | None) -> list[Path]:
    """Where to look for the daemon's status socket (see the module's doc)."""
    if state_dir:
        return [Path(state_dir) / SOCKET]
    folder = Path(os.path.abspath(port)).parent
    out: list[Path] = []
    for path in (folder / SOCKET, folder / ".run" / "state" / SOCKET, DEFAULT_STATE_DIR / SOCKET):
        if path not in out:
            out.append(path)
    return out


def read_document(path: Path, deadline: float) -> dict[str, Any] | None:
    """The status document at ``path``, or None (no socket there, no answer by
    ``deadline`` on the monotonic clock, not a document)."""
    try:
        if not stat.S_ISSOCK(os.stat(path).st_mode):
            return None
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(max(0.001, deadline - time.monotonic()))
            sock.connect(str(path))
            sock.sendall(b"\n")
            data = bytearray()
            while len(data) <= MAX_BYTES:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                sock.settimeout(left)
                chunk = sock.recv(65536)
                if not chunk:
                    break
                data += chunk
            else:
                return None
        doc = json.loads(data)
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def find_record(
    doc: Mapping[str, Any],
    code: ErrorCode,
    command: Command | None,
    sent_at: float,
    frame: bytes | None = None,
) -> dict[str, Any] | None:
    """The record of this error in a status document: its code, its command's words (or,
    for a frame that is no command, its bytes) and a time after ``sent_at``; None when the
    document holds none."""
    errors = doc.get("errors")
    records: list[Any] = []
    if isinstance(errors, dict):
        records += [errors.get("last"), errors.get("link")]
    motors = doc.get("motors")
    if isinstance(motors, list):
        records += [m.get("last_error") for m in motors if isinstance(m, dict)]
    words = None if command is None else describe(command)
    for r in records:
        if not isinstance(r, dict) or r.get("code") != code.short:
            continue
        if words is not None and r.get("command") != words:
            continue
        if words is None and frame is not None and r.get("frame") != frame.hex(" "):
            continue
        at = r.get("at_s")
        if isinstance(at, (int, float)) and at >= sent_at and isinstance(r.get("reason"), str):
            return r
    return None


def explain(
    code: ErrorCode | int,
    command: Command | None,
    port: str,
    sent_at: float,
    frame: bytes | None = None,
    env: Mapping[str, str] = os.environ,
) -> str:
    """The error's line (without "error: "): its code, and the daemon's reason when its
    status socket has this error's record, else the code's meaning for ``command``
    (``frame``: the bytes sent, for a frame that is no command)."""
    if not isinstance(code, ErrorCode):
        return f"unknown error code 0x{code:02x}"
    head = f"{code.short} {code.label.lower()}"
    deadline = time.monotonic() + STATUS_TIMEOUT_S
    for path in socket_paths(port, env.get(STATE_DIR_ENV)):
        doc = read_document(path, deadline)
        record = None if doc is None else find_record(doc, code, command, sent_at, frame)
        if record is not None:
            return f"{head}: {with_reason(record, command)}"
    return f"{head}: {meaning(code, command)}"


def with_reason(record: Mapping[str, Any], command: Command | None) -> str:
    """The daemon's reason, its motor, and what fixes it on this command line."""
    text = str(record["reason"])
    motor = record.get("motor")
    if isinstance(motor, int):
        text += f" (motor {motor})"
    fixes = record.get("fix")
    steps = []
    for name in fixes if isinstance(fixes, list) else []:
        target = _number(command) if not isinstance(motor, int) else motor
        words = fix_words(str(name), target) if target is not None else None
        if words is not None:
            steps.append(words)
    if steps:
        text += " — " + ", then ".join(steps)
    return text


def _number(command: Command | None) -> int | None:
    """The motor or pin ``command`` addresses."""
    for field in ("motor", "pin"):
        value = getattr(command, field, None)
        if isinstance(value, int):
            return value
    return None


def meaning(code: ErrorCode, command: Command | None) -> str:
    """What ``code`` means as the answer to ``command`` (None: a frame that is not a
    command): the command table's meaning for that command, with the commands that clear it
    on this command line, else the code's own (PROTOCOL.md §5)."""
    if command is None:
        return code.means[1]
    values = {p.name: getattr(command, p.name) for p in command.spec.params}
    gives = command.spec.gives_code(code)
    if gives is None:
        template, plain = code.means
        try:
            return template.format_map(values)
        except KeyError:  # the command has no such parameter (a motor, a waypoint)
            return plain
    text = gives.means.format_map(values)
    n = _number(command)
    fixes = [w for w in (fix_words(f, n) for f in gives.fix if n is not None) if w]
    return f"{text} — {', or '.join(fixes)}" if fixes else text
