"""The link's optional parts as the config, the command line and the environment ask for
them: the watch on the host's silence (``[link] timeout_ms``, ``timeout_action``:
:func:`silence_watch`), the trace recorder (``--trace``, ``[trace]``: :func:`open_trace`,
whose modules are imported only when a trace is asked for) and the count of the link
thread's CPU time by part (``MOTORCTL_LINK_CPU_PARTS=1``: :func:`cpu_parts`). The
assembler (daemon/start/assemble.py) hands them to the link it builds.

Threads: the main thread at start-up builds them; the silence watch's action then runs on
the link thread (the dispatcher's ``link_silent``).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from motorctl import __version__
from motorctl.daemon.config import Config
from motorctl.daemon.dispatcher import Dispatcher
from motorctl.daemon.errors import StartupError
from motorctl.daemon.link.cpu_parts import CpuParts
from motorctl.daemon.link.silence import SilenceWatch

if TYPE_CHECKING:  # imported when a trace is asked for (open_trace)
    from motorctl.daemon.link.recorder import TraceRecorder

log = logging.getLogger("motorctl")


def silence_watch(config: Config, dispatcher: Dispatcher, now: float) -> SilenceWatch:
    """``[link] timeout_ms`` and ``timeout_action``: the host's silence stops the motors
    (its silence counted from ``now``, on the link's clock)."""
    c = config.link
    hard = c.timeout_action == "hard"
    reason = f"link timeout: no byte from the host for {c.timeout_ms:g} ms"

    def act(now: float) -> list[str]:
        return dispatcher.link_silent(hard=hard, reason=reason)

    if c.timeout_ms > 0:
        log.info(
            "[link] timeout_ms = %g: the host's silence stops the motors in motion (%s)",
            c.timeout_ms,
            c.timeout_action,
        )
    return SilenceWatch(c.timeout_ms / 1000.0, act, now, c.timeout_action)


#: the environment variable that asks for the link thread's CPU time by part
CPU_PARTS_ENV = "MOTORCTL_LINK_CPU_PARTS"


def cpu_parts() -> CpuParts | None:
    """The link thread's CPU time counted by part (status ``link.cpu_parts``), when
    ``MOTORCTL_LINK_CPU_PARTS=1`` (bench/latency.py sets it); any other value is refused."""
    value = os.environ.get(CPU_PARTS_ENV, "")
    if value not in ("", "0", "1"):
        raise StartupError(f"{CPU_PARTS_ENV}={value!r}: 1 counts the link's CPU by part, 0 not")
    if value != "1":
        return None
    log.info("%s=1: the link thread's CPU time is counted by part", CPU_PARTS_ENV)
    return CpuParts()


def open_trace(option: Path | None, config: Config, where: str) -> TraceRecorder | None:
    """The link's trace recorder, when ``--trace`` or ``[trace] file`` asks for one (its
    modules imported only then)."""
    t = config.trace
    path = option.absolute() if option is not None else Path(t.file) if t.file else None
    if path is None:
        return None
    from motorctl.daemon.link.recorder import TraceRecorder
    from motorctl.protocol.capture.format import CaptureInfo

    c = config.link
    info = CaptureInfo(
        role="daemon",
        checksum=c.checksum,
        crc_covers_ack=c.crc_covers_ack,
        strict_padding=c.strict_padding,
        frame_gap_ms=c.frame_gap_ms,
        port=where,
        application=f"motorctld {__version__}",
    )
    recorder = TraceRecorder(
        path, info, max(4096, int(t.max_file_mb * (1 << 20))), t.files, time.monotonic()
    )
    try:
        recorder.open()
    except OSError as exc:
        raise StartupError(
            f"cannot write the trace file {path}: {exc.strerror or exc}; "
            "give --trace (or [trace] file) a writable path"
        ) from exc
    log.info("tracing the link to %s (%d files of %.3g MiB at most)", path, t.files, t.max_file_mb)
    return recorder
