"""Real-time set-up of the calling thread: CPU pinning, mlockall, SCHED_FIFO.

Only the step executor calls :func:`enter_realtime` (its thread, or its own process's main
thread); the rest of the daemon runs at normal priority and does not lock its memory.
Each step is optional and a refusal is a warning, not an error (tests and unprivileged
runs get best-effort timing).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
from dataclasses import dataclass

log = logging.getLogger("motorctl.rt")

_MCL_CURRENT = 1
_MCL_FUTURE = 2


@dataclass(frozen=True)
class RealtimeOptions:
    """``priority`` 0: no SCHED_FIFO; ``cpu`` -1: no pinning."""

    priority: int = 50
    lock_memory: bool = True
    cpu: int = -1


def lock_memory() -> str | None:
    """mlockall(MCL_CURRENT | MCL_FUTURE); returns why not, or None on success."""
    libc = ctypes.CDLL(None, use_errno=True)  # the interpreter's own libc (no ldconfig run)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        return os.strerror(ctypes.get_errno())
    return None


def set_realtime(priority: int) -> str | None:
    """SCHED_FIFO at ``priority`` for the calling thread; returns why not, or None."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError) as exc:
        return str(exc)
    return None


def enter_realtime(opts: RealtimeOptions, who: str) -> list[str]:
    """Apply ``opts`` to the calling thread; returns (and logs) the warnings."""
    warnings: list[str] = []
    if opts.cpu >= 0:
        try:
            os.sched_setaffinity(0, {opts.cpu})
        except OSError as exc:
            warnings.append(f"cannot pin {who} to CPU {opts.cpu}: {exc}")
    if opts.lock_memory:
        why = lock_memory()
        if why is not None:
            warnings.append(f"mlockall not permitted for {who} ({why}): memory may be paged out")
    if opts.priority > 0:
        why = set_realtime(opts.priority)
        if why is not None:
            warnings.append(
                f"SCHED_FIFO priority {opts.priority} not permitted for {who} ({why}): "
                "step timing is best effort"
            )
    for w in warnings:
        log.warning("%s", w)
    return warnings


class GcPolicy:
    """Automatic GC off while anything moves; objects alive at ready are frozen."""

    def ready(self) -> None:
        gc.collect()
        gc.freeze()

    def motion(self, active: bool) -> None:
        if active:
            gc.disable()
        else:
            gc.enable()
