"""The link thread's usual turn, counted exactly: Python opcodes and calls per command.

An in-process link (daemon/link/loop.py) with the daemon's real dispatcher, engine and
executor (the config's default: the step core in a process of its own, its planner thread
running), on one end of a socket pair instead of the PTY, so that only the link's own work
is counted; the other end is the host, which sends one command frame and reads its answer
per turn. Each measured turn runs under ``sys.settrace`` with ``f_trace_opcodes``: every
opcode and every Python call of the link thread's turn is counted, by function. Unlike CPU
time these counts do not move with the machine's load (docs/timing.md, "The link thread's
usual turn").

Prints, for each command asked for (``--command``, default IsReady and GetAbsPos), the
opcodes and calls per turn and the functions that cost the most; ``--json FILE``: all of
it.
"""

from __future__ import annotations

import argparse
import json
import select
import socket
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from motorctl.daemon.config import parse_config  # noqa: E402
from motorctl.daemon.link.loop import Link  # noqa: E402
from motorctl.daemon.start.assemble import Daemon  # noqa: E402
from motorctl.hal.interfaces import MonotonicClock  # noqa: E402
from motorctl.protocol.codec import (  # noqa: E402
    CodecOptions,
    Command,
    GetAbsPos,
    IsReady,
    encode_command,
)

CONFIG = '[[motors]]\nname = "a"\n[[motors]]\nname = "b"\n'
COMMANDS: dict[str, Command] = {"IsReady": IsReady(0), "GetAbsPos": GetAbsPos(0)}
WARM_UP = 200  # turns before the counted ones: caches filled, the specializing done


def count(
    link: Link, poller: select.poll, host: socket.socket, frame: bytes, turns: int
) -> dict[str, Any]:
    """Opcodes and calls of ``turns`` turns, each answering one ``frame``, by function
    (``poller``: the link's, as its ``serve`` makes it; the link registers its port there)."""
    for _ in range(WARM_UP):
        host.send(frame)
        link.turn(poller)
        host.recv(5)
    ops: Counter[str] = Counter()
    calls: Counter[str] = Counter()

    def tracer(frame_: Any, event: str, arg: object) -> Any:
        name = frame_.f_code.co_qualname
        if event == "call":
            calls[name] += 1
            frame_.f_trace_opcodes = True
        elif event == "opcode":
            ops[name] += 1
        return tracer

    for _ in range(turns):
        host.send(frame)
        time.sleep(0.001)  # the bytes are there when the turn polls, as in the usual turn
        sys.settrace(tracer)
        link.turn(poller)
        sys.settrace(None)
        if len(host.recv(5)) != 5:
            raise RuntimeError("no answer")
    by_function = {
        name: {"opcodes": round(ops[name] / turns, 1), "calls": round(calls[name] / turns, 1)}
        for name in sorted(ops, key=lambda n: -ops[n])
    }
    return {
        "opcodes": round(sum(ops.values()) / turns, 1),
        "calls": round(sum(calls.values()) / turns, 1),
        "by_function": by_function,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--command", choices=sorted(COMMANDS), action="append")
    ap.add_argument("--turns", type=int, default=100, help="counted turns per command")
    ap.add_argument("--top", type=int, default=12, help="functions printed per command")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    opts = CodecOptions()
    result: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        config = parse_config(CONFIG, "turn_opcodes.toml")
        daemon = Daemon.build(config, Path(tmp) / "state", MonotonicClock())
        engine = daemon.engine
        engine.executor.start()
        engine.start()
        ours, host = socket.socketpair()
        ours.setblocking(False)
        link = Link(ours.fileno(), daemon.dispatcher, opts, 0.01, 16)
        poller = select.poll()
        poller.register(link._wake_r, select.POLLIN)
        try:
            for name in args.command or list(COMMANDS):
                frame = encode_command(COMMANDS[name], opts)
                result[name] = count(link, poller, host, frame, args.turns)
        finally:
            link.close()
            engine.stop_threads()
            engine.executor.close()
            daemon.hw.close()
            ours.close()
            host.close()
    result["executor"] = type(engine.executor).__name__
    for name, got in result.items():
        if name == "executor":
            continue
        print(f"{name}: {got['opcodes']} opcodes, {got['calls']} calls per turn")
        for fn, n in list(got["by_function"].items())[: args.top]:
            print(f"  {n['opcodes']:7.1f} opcodes {n['calls']:4.1f} calls  {fn}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
