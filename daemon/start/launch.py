"""The ``motorctld`` command: the step executor's interpreter starts first, then the daemon.

The executor's process is the longest part of motorctld's start-up: a second Python
interpreter, then the step core's modules (``motion/executors/process/start.py``). Started
here, before the daemon imports its own modules, the two interpreters start side by side
and READY comes sooner (bench/startup.py, docs/service.md). It is started only for a command line
that serves (``--pty`` or ``--port``, none of the commands that print and exit) and when a
second CPU can run it; the daemon takes it over once it has read its config, or ends it at
once when the config has no use for it (the thread executor, no stepped motor) or the start
fails. ``python -m motorctl.daemon.start.main`` runs the same daemon without this head start.

A start that serves runs without the garbage collector's automatic collections from here
until READY: the imports build thousands of objects (every dataclass's methods, the command
table, the config schema) and the collector would look at all of them again and again, a
tenth of the start's CPU for no garbage worth it (docs/timing.md). The daemon collects
once, after READY (``rt.GcPolicy.ready``, daemon/start/serve.py), freezes what lives on
and turns automatic collection back on. The executor's bootstrap turns it off on its first
line too (``motion/executors/process/start.py``): that process collects while it waits
and runs without automatic collection once ready, as it did before.

The daemon's modules are imported with the compiled code of their dataclasses' methods
that the package's build recorded (``motorctl/dataclass_code.py``), instead of compiling
each method again: the largest part of those imports before (docs/timing.md).

``motorctld --status --watch`` (the live monitor) ends on SIGINT and SIGTERM from this
command's first instruction on (``daemon/status/monitor.py``, ``end_on_signals``): they are
taken over before anything else is imported, and an end while the daemon's modules are
still being imported is as quiet as one while the monitor draws.

Owners: the main thread, before anything else runs.
"""

from __future__ import annotations

import gc
import os
import sys
from collections.abc import Sequence

#: Options after which motorctld prints something and exits instead of serving.
ONE_SHOT = frozenset(
    {
        "--check-config",
        "--print-default-config",
        "--probe",
        "--status",
        "--histogram",
        "--help",
        "-h",
        "--version",
    }
)


def serves(argv: Sequence[str]) -> bool:
    """Whether this command line would serve (a quick look; argparse decides later)."""
    options = {arg.split("=", 1)[0] for arg in argv if arg.startswith("-")}
    return bool(options & {"--pty", "--port"}) and not options & ONE_SHOT


def watches(argv: Sequence[str]) -> bool:
    """Whether this command line is the live monitor's (``--status --watch``)."""
    return {"--status", "--watch"} <= set(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if watches(args):
        from motorctl.daemon.status import monitor

        monitor.end_on_signals()
        from motorctl.daemon.start.main import main as watch_main

        return watch_main(args)
    serving = serves(args)
    if serving:
        gc.disable()  # until the collection after READY (rt.GcPolicy.ready)
    from motorctl.motion.executors.process.start import WaitingInterpreter

    early = None
    if serving and len(os.sched_getaffinity(0)) > 1:
        try:
            early = WaitingInterpreter.start()
        except OSError:
            early = None  # the daemon starts it itself, and reports what is wrong then
    from motorctl.dataclass_code import CodeCache

    codes = CodeCache.load()  # the build's file; main() logs what it gave, or why not
    with codes.use():
        from motorctl.daemon.start.main import main as daemon_main

    return daemon_main(args, executor_process=early, dataclass_code=codes)


if __name__ == "__main__":
    raise SystemExit(main())
