"""Real-time set-up of the calling thread, and what it got: CPU pinning, mlockall, SCHED_FIFO.

Only the step executor calls :func:`enter_realtime` (its thread, or its own process's main
thread); the rest of the daemon runs at normal priority and does not lock its memory.
Each request is optional and a refusal is no error (tests and unprivileged runs get
best-effort timing), but never a silent one: :func:`enter_realtime` returns a
:class:`RealtimeReport`, each request granted, refused (the kernel's error, what made the
kernel say it, and the fix) or not asked, with the kernel's preemption model. The executor
hands it to the daemon (the process executor through its shared block), which shows it in
the READY line, ``motorctld --status`` and systemd's STATUS= (docs/timing.md, "Real time:
what the executor got").

Why a refusal happened is read from what decides it (:class:`Privileges`: the process's
RLIMIT_RTPRIO and RLIMIT_MEMLOCK, its capabilities, ``kernel.sched_rt_runtime_us``, its
cgroup): a SCHED_FIFO refused although the limits allow it is the kernel's RT group
scheduling, which gives the process's cgroup no real-time time.

Threads: the caller's; nothing here keeps state.
"""

from __future__ import annotations

import ctypes
import errno
import gc
import itertools
import logging
import os
import resource
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("motorctl.rt")

_MCL_CURRENT = 1
_MCL_FUTURE = 2
#: capability bits (linux/capability.h)
CAP_IPC_LOCK = 14
CAP_SYS_NICE = 23

GRANTED, REFUSED, NOT_ASKED = "granted", "refused", "not asked"
#: the requests, in the order they are made and shown
ITEMS = ("cpu_affinity", "memory_lock", "sched_fifo")
#: the longest reason or fix kept (the report crosses a fixed-size cell of shared memory)
TEXT_MAX = 600


@dataclass(frozen=True)
class RealtimeOptions:
    """``priority`` 0: no SCHED_FIFO; ``cpu`` -1: no pinning."""

    priority: int = 50
    lock_memory: bool = True
    cpu: int = -1


@dataclass(frozen=True)
class Outcome:
    """One request: ``state`` (granted, refused, not asked); ``what`` was asked ("SCHED_FIFO
    50", "mlockall", "CPU 3"; not asked: the setting that leaves it off); refused: the
    kernel's ``error`` (its errno name), the ``reason`` in words and the ``fix``."""

    state: str
    what: str
    error: str | None = None
    reason: str | None = None
    fix: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "what": self.what,
            "error": self.error,
            "reason": self.reason,
            "fix": self.fix,
        }


@dataclass(frozen=True)
class RealtimeReport:
    """What the step executor asked for and got, and the kernel it runs on."""

    cpu_affinity: Outcome
    memory_lock: Outcome
    sched_fifo: Outcome
    kernel: str = ""  # the release (``uname -r``)
    preempt_rt: bool = False

    def outcomes(self) -> dict[str, Outcome]:
        return {name: getattr(self, name) for name in ITEMS}

    def refused(self) -> list[str]:
        """The requests refused (their names in :data:`ITEMS`)."""
        return [name for name, o in self.outcomes().items() if o.state == REFUSED]

    def as_dict(self) -> dict[str, Any]:
        """The report as the status document has it (``executor.realtime``)."""
        out: dict[str, Any] = {name: o.as_dict() for name, o in self.outcomes().items()}
        out["refused"] = self.refused()
        out["kernel"] = {"release": self.kernel, "preempt_rt": self.preempt_rt}
        return out

    @classmethod
    def from_dict(cls, data: Any) -> RealtimeReport:
        """Back from :meth:`as_dict` (what the executor process handed over); ValueError
        for anything else."""
        try:
            items = {
                name: Outcome(**{k: data[name][k] for k in Outcome.__dataclass_fields__})
                for name in ITEMS
            }
            release, rt = str(data["kernel"]["release"]), bool(data["kernel"]["preempt_rt"])
            return cls(**items, kernel=release, preempt_rt=rt)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a real-time report: {exc!r}") from None

    def words(self) -> str:
        """The report in one line of the READY line (no "; " in it): what was granted, what
        refused and by which error, the kernel's preemption model."""
        parts: list[str] = []
        for o in (self.sched_fifo, self.memory_lock, self.cpu_affinity):  # weightiest first
            if o.state == GRANTED:
                parts.append("memory locked" if o.what == "mlockall" else o.what)
            elif o.state == REFUSED:
                parts.append(f"{o.what} REFUSED ({o.error})")
        kernel = "PREEMPT_RT kernel" if self.preempt_rt else "kernel not PREEMPT_RT"
        if not parts:
            off = ", ".join(o.what.removeprefix("[step_thread] ") for o in self.outcomes().values())
            return f"real time not asked ([step_thread] {off})"
        text = f"real time {', '.join(parts)}, {kernel}"
        if self.refused():
            text += ": steps best effort, 'motorctld --status' says why and the fix"
        return text

    def warnings(self, who: str) -> list[str]:
        """A line for the log per refused request: what, why, the fix."""
        return [
            f"{o.what} refused for {who}: {o.reason}; {o.fix}"
            for o in self.outcomes().values()
            if o.state == REFUSED
        ]


@dataclass(frozen=True)
class Privileges:
    """What decides whether the kernel grants a request: the process's limits (None:
    unlimited), its effective capabilities, ``kernel.sched_rt_runtime_us`` (None: not
    readable), its cgroup (``/proc/self/cgroup``'s path, None: unknown) and the CPUs it may
    run on."""

    rtprio_limit: int | None = 0
    memlock_limit: int | None = 0
    cap_sys_nice: bool = False
    cap_ipc_lock: bool = False
    rt_runtime_us: int | None = None
    cgroup: str | None = None
    cpus: frozenset[int] = field(default_factory=frozenset)


def _limit(which: int) -> int | None:
    soft = resource.getrlimit(which)[0]
    return None if soft == resource.RLIM_INFINITY else int(soft)


def _text(path: str) -> str | None:
    try:
        return Path(path).read_text(errors="replace")
    except OSError:
        return None


def read_privileges() -> Privileges:
    """This process's :class:`Privileges`, from the kernel."""
    caps = 0
    for line in (_text("/proc/self/status") or "").splitlines():
        if line.startswith("CapEff:"):
            caps = int(line.split()[1], 16)
    runtime = (_text("/proc/sys/kernel/sched_rt_runtime_us") or "").strip()
    cgroup = None
    for line in (_text("/proc/self/cgroup") or "").splitlines():
        _, controllers, path = line.split(":", 2)
        if controllers in ("", "cpu", "cpu,cpuacct") or "cpu" in controllers.split(","):
            cgroup = path
    return Privileges(
        rtprio_limit=_limit(resource.RLIMIT_RTPRIO),
        memlock_limit=_limit(resource.RLIMIT_MEMLOCK),
        cap_sys_nice=bool(caps >> CAP_SYS_NICE & 1),
        cap_ipc_lock=bool(caps >> CAP_IPC_LOCK & 1),
        rt_runtime_us=int(runtime) if runtime.lstrip("-").isdigit() else None,
        cgroup=cgroup,
        cpus=frozenset(os.sched_getaffinity(0)),
    )


def _error(exc: OSError) -> tuple[str, str]:
    """The errno's name and the kernel's words for it."""
    code = exc.errno or 0
    return errno.errorcode.get(code, f"errno {code}"), exc.strerror or os.strerror(code)


def _cut(text: str) -> str:
    return text if len(text) <= TEXT_MAX else text[: TEXT_MAX - 3] + "..."


def fifo_refused(exc: OSError, priority: int, p: Privileges) -> Outcome:
    """SCHED_FIFO at ``priority`` refused with ``exc``: why, and the fix."""
    name, words = _error(exc)
    what = f"SCHED_FIFO {priority}"
    if exc.errno != errno.EPERM:
        reason = f"{name} ({words})"
        fix = "[step_thread] priority: 1..99, or 0 to not ask"
    elif p.rt_runtime_us == 0:
        reason = f"{name} ({words}): kernel.sched_rt_runtime_us is 0, no real-time time at all"
        fix = "sysctl kernel.sched_rt_runtime_us=950000 (or -1), e.g. in /etc/sysctl.d/"
    elif p.cap_sys_nice or p.rtprio_limit is None or p.rtprio_limit >= priority:
        limit = "unlimited" if p.rtprio_limit is None else p.rtprio_limit
        allowed = "CAP_SYS_NICE" if p.cap_sys_nice else f"RLIMIT_RTPRIO {limit}"
        where = f" {p.cgroup}" if p.cgroup else ""
        reason = (
            f"{name} ({words}) although {allowed} allows it: the kernel's RT group scheduling "
            f"(CONFIG_RT_GROUP_SCHED) gives the process's cgroup{where} no real-time time"
        )
        fix = (
            "give that cgroup a real-time budget (cgroup v1: its cpu.rt_runtime_us, e.g. "
            "950000, within kernel.sched_rt_runtime_us), or boot a kernel without "
            "CONFIG_RT_GROUP_SCHED (docs/raspberry-pi.md, 'Real time')"
        )
    else:
        reason = (
            f"{name} ({words}): RLIMIT_RTPRIO is {p.rtprio_limit}, below {priority}, and "
            "the process lacks CAP_SYS_NICE"
        )
        fix = (
            f"run it as root, or with LimitRTPRIO={priority} or more (the motorctld unit "
            "has LimitRTPRIO=99), or grant it CAP_SYS_NICE"
        )
    return Outcome(REFUSED, what, name, _cut(reason), _cut(fix))


def memory_refused(exc: OSError, p: Privileges) -> Outcome:
    """mlockall refused with ``exc``: why, and the fix."""
    name, words = _error(exc)
    if exc.errno in (errno.ENOMEM, errno.EPERM) and not p.cap_ipc_lock:
        limit = "unlimited" if p.memlock_limit is None else f"{p.memlock_limit // 1024} KiB"
        reason = (
            f"{name} ({words}): RLIMIT_MEMLOCK is {limit}, less than the process "
            "takes, and the process lacks CAP_IPC_LOCK"
        )
    else:
        reason = f"{name} ({words})"
    fix = (
        "run it as root, or with LimitMEMLOCK=infinity (the motorctld unit has it); or "
        "[step_thread] lock_memory = false to not ask (pages may then be swapped out)"
    )
    return Outcome(REFUSED, "mlockall", name, _cut(reason), _cut(fix))


def cpu_refused(exc: OSError, cpu: int, p: Privileges) -> Outcome:
    """Pinning to ``cpu`` refused with ``exc``: why, and the fix."""
    name, words = _error(exc)
    allowed = ",".join(str(c) for c in sorted(p.cpus)) or "none"
    reason = (
        f"{name} ({words}): CPU {cpu} is not one this process may run on (online, in its "
        f"cpuset: {allowed})"
    )
    fix = f"[step_thread] cpu = one of {allowed}, or -1 to not pin"
    return Outcome(REFUSED, f"CPU {cpu}", name, _cut(reason), _cut(fix))


def kernel_preempt_rt(version: str, realtime_flag: str | None = None) -> bool:
    """Whether the kernel is PREEMPT_RT: its version string (``uname -v``) says so
    ("PREEMPT_RT"; "PREEMPT RT" in RT patch sets before 5.x), or ``/sys/kernel/realtime``
    (``realtime_flag``, its text) is 1, which the RT patch set adds and mainline PREEMPT_RT
    (6.12 on) does not."""
    words = version.split()
    if "PREEMPT_RT" in words or ("PREEMPT", "RT") in itertools.pairwise(words):
        return True
    return (realtime_flag or "").strip() == "1"


def running_kernel() -> tuple[str, bool]:
    """This machine's kernel release and whether it is PREEMPT_RT."""
    uname = os.uname()
    return uname.release, kernel_preempt_rt(uname.version, _text("/sys/kernel/realtime"))


def lock_memory() -> OSError | None:
    """mlockall(MCL_CURRENT | MCL_FUTURE); the error, or None on success."""
    libc = ctypes.CDLL(None, use_errno=True)  # the interpreter's own libc (no ldconfig run)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        code = ctypes.get_errno()
        return OSError(code, os.strerror(code))
    return None


def unlock_memory() -> None:
    """munlockall(): undo :func:`lock_memory` (the probe's measurement, not the executor)."""
    ctypes.CDLL(None, use_errno=True).munlockall()


def enter_realtime(
    opts: RealtimeOptions,
    who: str,
    privileges: Callable[[], Privileges] = read_privileges,
    quiet: bool = False,
) -> RealtimeReport:
    """Apply ``opts`` to the calling thread: what it got (a refusal is logged as a warning
    with its reason and fix, unless ``quiet``). ``privileges``: read when something was
    refused, to say why."""
    known: list[Privileges] = []

    def why() -> Privileges:
        if not known:
            known.append(privileges())
        return known[0]

    cpu = Outcome(NOT_ASKED, "[step_thread] cpu = -1")
    if opts.cpu >= 0:
        try:
            os.sched_setaffinity(0, {opts.cpu})
            cpu = Outcome(GRANTED, f"CPU {opts.cpu}")
        except OSError as exc:
            cpu = cpu_refused(exc, opts.cpu, why())
    memory = Outcome(NOT_ASKED, "[step_thread] lock_memory = false")
    if opts.lock_memory:
        failed = lock_memory()
        memory = Outcome(GRANTED, "mlockall") if failed is None else memory_refused(failed, why())
    fifo = Outcome(NOT_ASKED, "[step_thread] priority = 0")
    if opts.priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(opts.priority))
            fifo = Outcome(GRANTED, f"SCHED_FIFO {opts.priority}")
        except OSError as exc:
            fifo = fifo_refused(exc, opts.priority, why())
    release, rt = running_kernel()
    report = RealtimeReport(cpu, memory, fifo, release, rt)
    for w in [] if quiet else report.warnings(who):
        log.warning("%s", w)
    return report


class GcPolicy:
    """Automatic GC off while anything moves; objects alive at ready are frozen."""

    def ready(self) -> None:
        """The start's garbage collected, what lives on frozen, automatic collection on (a
        start that serves runs without it: daemon/start/launch.py). Before the link serves:
        nothing moves yet."""
        gc.collect()
        gc.freeze()
        gc.enable()

    def motion(self, active: bool) -> None:
        if active:
            gc.disable()
        else:
            gc.enable()
