"""``motorctld --probe``'s platform check: what decides step timing on this board, measured
and read from the kernel, ending with plain advice (docs/timing.md, "Checking a platform").

Facts come from files under three roots, ``/proc``, ``/sys`` and ``/etc`` (:class:`Roots`),
so tests point them at a fake tree: the kernel's preemption model (its version string, i.e.
``uname -v``, or ``/sys/kernel/realtime``; ``/sys/kernel/debug/sched/preempt`` or
``preempt=`` on the command line for a PREEMPT_DYNAMIC kernel), the OS release (for the way
to an RT kernel on it: daemon/start/platform_kernel.py), ``kernel.sched_rt_runtime_us``, each
CPU's cpufreq governor, the isolated and nohz_full CPUs, the board's model (device tree),
and where the board reports them under-voltage and throttling: a Raspberry Pi's ``rpi_volt``
hwmon device (``in0_lcrit_alarm``: under-voltage seen in the driver's last poll, every 2 s)
and, on kernels that still have it, its firmware's ``get_throttled`` (hex bits: 0
under-voltage now, 1 ARM frequency capped, 2 throttled, 3 soft temperature limit; 16-19 the
same "has occurred", since boot or since the hwmon driver last cleared them).

On a thread of its own the check asks for the real time the executor asks for (its CPU,
mlockall, SCHED_FIFO: motion/rt.py) and reports what it got, each refusal with its reason
and fix; the latency measurement then runs timed sleeps for a few seconds on that thread, at
what was granted (it says so when something was not, and measures at normal priority: never
an error). It measures what the executor's timer wake-ups see: the step executor sleeps
until ``spin_us`` before a step and busy-waits the rest, so a wake-up later than that makes
the step late.

Threads: :func:`measure_latency` starts and joins its own thread; the rest is pure reading.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from motorctl.daemon.config.model import MICROSTEPS_UNSAID
from motorctl.daemon.start.platform_kernel import OsRelease, read_os_release, rt_kernel_advice
from motorctl.daemon.status.summary import realtime_lines
from motorctl.motion.executors.base import LagRule, lag_full_steps
from motorctl.motion.executors.config import StepThreadConfig
from motorctl.motion.latency import LatencyStats
from motorctl.motion.rt import (
    GRANTED,
    REFUSED,
    RealtimeOptions,
    RealtimeReport,
    enter_realtime,
    kernel_preempt_rt,
    unlock_memory,
)
from motorctl.schema import default_of

#: get_throttled's bits (the Raspberry Pi firmware's)
THROTTLED_BITS = {
    0: "under-voltage now",
    1: "ARM frequency capped now",
    2: "throttled now",
    3: "soft temperature limit now",
    16: "under-voltage has occurred",
    17: "ARM frequency capping has occurred",
    18: "throttling has occurred",
    19: "soft temperature limit has occurred",
}
INTERVAL_S = 0.001  # one timed sleep per millisecond


@dataclass(frozen=True)
class Roots:
    """Where the kernel's files and the OS release are (tests: a fake tree)."""

    proc: Path = Path("/proc")
    sys: Path = Path("/sys")
    etc: Path = Path("/etc")


@dataclass
class Platform:
    """What was found; None (or empty) where the kernel or board does not say."""

    kernel: str | None = None
    version: str | None = None
    rt: bool = False
    preempt: str = "unknown"
    rt_runtime_us: int | None = None
    rt_period_us: int | None = None
    online: set[int] = field(default_factory=set)
    isolated: set[int] = field(default_factory=set)
    nohz_full: set[int] = field(default_factory=set)
    governors: dict[int, str] = field(default_factory=dict)
    model: str | None = None
    undervoltage: bool | None = None
    throttled: int | None = None
    os_release: OsRelease | None = None
    machine: str = ""  # uname -m


@dataclass
class Latency:
    """Timed sleeps' lateness: what ran, where, how late."""

    samples: int
    p50_us: float
    p99_us: float
    max_us: float
    policy: str  # e.g. "SCHED_FIFO 50 on CPU 3", "normal priority"
    notes: list[str] = field(default_factory=list)  # what was refused, and why


def _read(path: Path) -> str | None:
    try:
        return path.read_text(errors="replace").strip("\x00\n ")
    except OSError:
        return None


def _int(path: Path) -> int | None:
    text = _read(path)
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def parse_cpulist(text: str | None) -> set[int]:
    """The kernel's CPU list format ("0-2,5", "" for none); unreadable parts are skipped."""
    cpus: set[int] = set()
    for part in (text or "").replace("\n", ",").split(","):
        part = part.strip()
        lo, _, hi = part.partition("-")
        if lo.isdigit() and (not hi or hi.isdigit()):
            cpus.update(range(int(lo), int(hi or lo) + 1))
    return cpus


def _cmdline_value(cmdline: str, key: str) -> str | None:
    for word in cmdline.split():
        if word.startswith(key + "="):
            return word.split("=", 1)[1]
    return None


def _debugfs_mounted(roots: Roots) -> bool:
    """Whether debugfs is mounted (``/proc/mounts``) where the preemption mode is read."""
    where = str(roots.sys / "kernel" / "debug")
    for line in (_read(roots.proc / "mounts") or "").splitlines():
        fields = line.split()
        if len(fields) >= 3 and fields[2] == "debugfs" and fields[1] == where:
            return True
    return False


def _preempt_unreadable(roots: Roots, euid: int) -> str:
    """Why ``/sys/kernel/debug/sched/preempt`` could not be read, and the fix."""
    if euid != 0:
        return "needs root and debugfs: run --probe as root"
    if not _debugfs_mounted(roots):
        return (
            "debugfs is not mounted: 'mount -t debugfs none /sys/kernel/debug', then run "
            "--probe again"
        )
    return "missing: a kernel without CONFIG_SCHED_DEBUG"


def read_platform(
    roots: Roots = Roots(), euid: int | None = None, machine: str | None = None
) -> Platform:
    """What the kernel, the board and the OS release say (``euid``: whose eyes read it;
    default: this process's, which decides what a missing debugfs file means; ``machine``:
    ``uname -m``, default this machine's)."""
    euid = os.geteuid() if euid is None else euid
    p = Platform(machine=os.uname().machine if machine is None else machine)
    p.os_release = read_os_release(roots.etc)
    kernel = roots.proc / "sys" / "kernel"
    p.kernel = _read(kernel / "osrelease")
    p.version = _read(kernel / "version")
    cmdline = _read(roots.proc / "cmdline") or ""
    _read_preemption(p, roots, cmdline, euid)
    p.rt_runtime_us = _int(kernel / "sched_rt_runtime_us")
    p.rt_period_us = _int(kernel / "sched_rt_period_us")
    cpu_dir = roots.sys / "devices" / "system" / "cpu"
    p.online = parse_cpulist(_read(cpu_dir / "online"))
    p.isolated = parse_cpulist(_read(cpu_dir / "isolated")) or parse_cpulist(
        _cmdline_value(cmdline, "isolcpus")
    )
    p.nohz_full = parse_cpulist(_read(cpu_dir / "nohz_full"))
    for gov in sorted(cpu_dir.glob("cpu[0-9]*/cpufreq/scaling_governor")):
        name = gov.parent.parent.name.removeprefix("cpu")
        text = _read(gov)
        if name.isdigit() and text:
            p.governors[int(name)] = text
    p.model = _read(roots.proc / "device-tree" / "model") or _read(
        roots.sys / "firmware" / "devicetree" / "base" / "model"
    )
    _read_power(p, roots)
    return p


def _read_preemption(p: Platform, roots: Roots, cmdline: str, euid: int) -> None:
    """The kernel's preemption model (``p.rt``, ``p.preempt``), from its version (``uname
    -v``), its realtime flag (the RT patch set's; mainline PREEMPT_RT has none), debugfs's
    preempt mode or the command line's ``preempt=``."""
    version_words = (p.version or "").split()
    p.rt = kernel_preempt_rt(p.version or "", _read(roots.sys / "kernel" / "realtime"))
    if p.rt:
        p.preempt = "PREEMPT_RT"
    elif "PREEMPT_DYNAMIC" in version_words:
        modes = (_read(roots.sys / "kernel" / "debug" / "sched" / "preempt") or "").split()
        current = next((m.strip("()") for m in modes if m.startswith("(")), None)
        current = current or _cmdline_value(cmdline, "preempt")
        p.preempt = (
            f"{current} (PREEMPT_DYNAMIC)"
            if current
            else "PREEMPT_DYNAMIC (mode not readable: /sys/kernel/debug/sched/preempt "
            f"{_preempt_unreadable(roots, euid)}; or set preempt= on the kernel command line)"
        )
    elif "PREEMPT" in version_words:
        p.preempt = "full (PREEMPT)"
    elif p.version is not None:
        p.preempt = "none or voluntary (no PREEMPT in the kernel version)"


def _read_power(p: Platform, roots: Roots) -> None:
    """The board's power: a Raspberry Pi's under-voltage alarm and its firmware's throttled
    bits (``p.undervoltage``, ``p.throttled``)."""
    for hwmon in sorted((roots.sys / "class" / "hwmon").glob("hwmon*")):
        if _read(hwmon / "name") == "rpi_volt":
            alarm = _read(hwmon / "in0_lcrit_alarm")
            if alarm in ("0", "1"):
                p.undervoltage = alarm == "1"
    platform_dir = roots.sys / "devices" / "platform"
    for pattern in (
        "soc/soc:firmware/get_throttled",
        "soc*/*firmware*/get_throttled",
        "*firmware*/get_throttled",
    ):
        found = sorted(platform_dir.glob(pattern))
        text = _read(found[0]) if found else None
        if text:
            try:
                p.throttled = int(text, 16)
            except ValueError:
                continue
            break


def throttled_text(bits: int) -> list[str]:
    return [text for bit, text in THROTTLED_BITS.items() if bits >> bit & 1] + [
        f"bit {b} (unknown)" for b in range(32) if bits >> b & 1 and b not in THROTTLED_BITS
    ]


def measure_latency(
    seconds: float,
    opts: RealtimeOptions,
    enter: Callable[[RealtimeOptions], RealtimeReport] = lambda o: enter_realtime(
        o, "the probe's thread", quiet=True
    ),
    interval_s: float = INTERVAL_S,
) -> tuple[RealtimeReport, Latency | None]:
    """On a new thread: ask for the real time the step executor asks for (``opts``, the
    config's [step_thread]; ``enter`` asks) and say what it got, then (``seconds`` > 0)
    time sleeps of ``interval_s`` for ``seconds`` at whatever was granted. A refusal is
    noted, never raised; memory locked for the measurement is unlocked after it."""
    stats = LatencyStats(threshold_s=1.0)
    got: list[RealtimeReport] = []

    def run() -> None:
        got.append(enter(opts))
        step = round(interval_s * 1e9)
        end = time.perf_counter_ns() + round(seconds * 1e9)
        while seconds > 0:
            due = time.perf_counter_ns() + step
            if due > end:
                break
            time.sleep(step / 1e9)
            stats.record_ns(time.perf_counter_ns() - due)

    thread = threading.Thread(target=run, name="motorctl-probe-latency", daemon=True)
    thread.start()
    thread.join()
    report = got[0]
    if report.memory_lock.state == GRANTED:
        unlock_memory()
    if seconds <= 0:
        return report, None
    summary = stats.summary()
    fifo, cpu = report.sched_fifo, report.cpu_affinity
    policy = fifo.what if fifo.state == GRANTED else "normal priority"
    if cpu.state == GRANTED:
        policy += f" on {cpu.what}"
    notes = [
        f"{o.what} refused (see 'real time' above): measured "
        f"{'at normal priority' if o is fifo else 'on any CPU'}"
        for o in (fifo, cpu)
        if o.state == REFUSED
    ]
    latency = Latency(
        samples=stats.count,
        p50_us=float(summary["p50_us"]),
        p99_us=float(summary["p99_us"]),
        max_us=float(summary["max_us"]),
        policy=policy,
        notes=notes,
    )
    return report, latency


@dataclass(frozen=True)
class MotorRate:
    """A motor's fastest step rate and how its lateness is judged (docs/timing.md, "Late
    steps: slide, or stop"): ``microsteps`` None when the config does not say (16 then),
    ``loses_steps`` False for the mock's simulated motors."""

    name: str
    max_speed: float
    microsteps: int | None
    start_speed: float  # the config's, as max_lag_full_steps ([[motors]]: their defaults)
    max_lag_full_steps: float
    loses_steps: bool = True


@dataclass(frozen=True)
class TimingConfig:
    """What of [step_thread] the advice needs (its defaults: the config's)."""

    cpu: int = default_of(StepThreadConfig, "cpu")
    priority: int = default_of(StepThreadConfig, "priority")
    spin_us: float = default_of(StepThreadConfig, "spin_us")
    executor: str = default_of(StepThreadConfig, "executor")


def advice(
    p: Platform, lat: Latency | None, cfg: TimingConfig, motors: Sequence[MotorRate]
) -> list[str]:
    """Plain advice, most important first; an empty list: nothing to change."""
    out = board_advice(p) + cpu_advice(p, cfg)
    if lat is not None and lat.samples:
        if lat.p99_us > cfg.spin_us:
            out.append(
                f"1 % of wake-ups are later than {lat.p99_us:,.0f} us, more than "
                f"step_thread.spin_us ({cfg.spin_us:,.0f}), which busy-waits that "
                "part away: those steps come late"
            )
        out += lag_advice(lat, motors)
    return out


def board_advice(p: Platform) -> list[str]:
    """The board's power and the kernel's scheduling: under-voltage, PREEMPT_RT, RT
    throttling, the cpufreq governors."""
    out: list[str] = []
    if p.undervoltage or (p.throttled is not None and p.throttled & 0x5):
        out.append(
            "the board reports under-voltage or throttling: use a stronger power "
            "supply (and cooling); a throttled CPU runs every step slower"
        )
    elif p.throttled is not None and p.throttled & 0x50000:
        out.append(
            "the board has seen under-voltage or throttling since boot: check the power supply"
        )
    if p.version is not None and not p.rt:
        way = rt_kernel_advice(p.model, p.os_release, p.kernel, p.machine)
        out.append(f"the kernel is not PREEMPT_RT, which bounds the executor's wake-ups: {way}")
    if p.rt_runtime_us is not None and p.rt_runtime_us != -1:
        period = p.rt_period_us or 1_000_000
        parked = max(0, period - p.rt_runtime_us) / 1000
        out.append(
            f"kernel.sched_rt_runtime_us is {p.rt_runtime_us}: a busy SCHED_FIFO "
            f"executor is parked {parked:.0f} ms of every {period / 1000:.0f} ms; set "
            "'sysctl kernel.sched_rt_runtime_us=-1' (e.g. in /etc/sysctl.d/) on a "
            "multi-core board"
        )
    slow = sorted({g for g in p.governors.values() if g != "performance"})
    if slow:
        out.append(
            f"cpufreq governor {', '.join(slow)}: set 'performance' (frequency changes "
            "delay wake-ups), e.g. cpufreq.default_governor=performance on the kernel "
            "command line"
        )
    return out


def cpu_advice(p: Platform, cfg: TimingConfig) -> list[str]:
    """The executor's CPU (isolated, online) and its real-time priority."""
    out: list[str] = []
    if cfg.cpu < 0:
        spare = max(p.online) if len(p.online) > 1 else None
        example = (
            f" (e.g. isolcpus={spare} nohz_full={spare} on the kernel command line, "
            f"then [step_thread] cpu = {spare})"
            if spare is not None
            else ""
        )
        out.append(f"isolate a CPU for the executor{example}")
    elif p.online and cfg.cpu not in p.online:
        out.append(
            f"[step_thread] cpu = {cfg.cpu} is not an online CPU "
            f"({_cpus(p.online)}): choose one of them"
        )
    elif cfg.cpu not in p.isolated:
        out.append(
            f"the executor's CPU {cfg.cpu} is not isolated: add isolcpus={cfg.cpu} "
            f"nohz_full={cfg.cpu} to the kernel command line"
        )
    if cfg.priority == 0:
        out.append(
            "[step_thread] priority = 0: the executor runs without real-time priority;"
            " set it (e.g. 50)"
        )
    return out


def lag_advice(lat: Latency, motors: Sequence[MotorRate]) -> list[str]:
    """Each group of alike motors: its lag after the worst wake-up measured, and whether
    that is beyond its ``max_lag_full_steps`` (docs/timing.md, "Late steps: slide, or
    stop")."""
    out: list[str] = []
    groups: dict[tuple[float, int | None, float, float, bool], list[str]] = {}
    for m in motors:  # motors alike share a line
        key = (m.max_speed, m.microsteps, m.start_speed, m.max_lag_full_steps, m.loses_steps)
        groups.setdefault(key, []).append(m.name)
    for (rate, microsteps, start, tolerance, loses), names in groups.items():
        micro = microsteps or MICROSTEPS_UNSAID
        rule = LagRule(micro, start, tolerance)  # the step core's own rule
        late_s = lat.max_us * 1e-6
        lag = lag_full_steps(late_s, 1 / rate, micro)
        known = "" if microsteps else f"; microsteps not in the config: {micro} assumed"
        which = f"motor{'s' if len(names) > 1 else ''} {', '.join(names)}"
        out.append(
            f"max lag at {rate:,.0f} step/s with {micro} microsteps would be "
            f"{lag:,.2f} full steps ({lat.max_us * 1e-6 * rate:,.1f} steps) after "
            f"the worst wake-up ({which}{known})"
        )
        if rule.loses_steps_at(late_s, rate):
            safe = rule.fastest_safe_rate(late_s)
            if loses:
                out.append(
                    f"that is beyond max_lag_full_steps ({tolerance:g}): a wake-up "
                    f"that late stops {which} with E4 'step timing lost' above "
                    f"{safe:,.0f} step/s; make the platform steadier (above) or "
                    "keep them slower"
                )
            else:
                out.append(
                    f"beyond max_lag_full_steps ({tolerance:g}) above {safe:,.0f} "
                    f"step/s: the mock's simulated {which} slide instead; real "
                    "motors there would stop with E4 'step timing lost'"
                )
    return out


def _cpus(cpus: set[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus)) or "none"


def report(
    p: Platform,
    lat: Latency | None,
    cfg: TimingConfig,
    motors: Sequence[MotorRate],
    skipped: str | None = None,
    rt: RealtimeReport | None = None,
) -> str:
    """The platform section of ``--probe``; ``rt``: what the probe got when it asked for
    the step executor's real time."""
    lines = ["platform (what decides step timing):"]
    lines.append(f"  board: {p.model or 'not reported (no device-tree model)'}")
    lines.append(f"  kernel: {p.kernel or '?'}; preemption: {p.preempt}")
    runtime = (
        "not readable"
        if p.rt_runtime_us is None
        else (
            "-1 (no RT throttling)"
            if p.rt_runtime_us == -1
            else f"{p.rt_runtime_us} of {p.rt_period_us or '?'} (RT throttling on)"
        )
    )
    lines.append(f"  kernel.sched_rt_runtime_us: {runtime}")
    if p.governors:
        by_gov: dict[str, set[int]] = {}
        for c, g in p.governors.items():
            by_gov.setdefault(g, set()).add(c)
        govs = "; ".join(f"{g} (CPU {_cpus(cs)})" for g, cs in sorted(by_gov.items()))
    else:
        govs = "no cpufreq (fixed frequency, or not exposed)"
    lines.append(f"  cpufreq governor: {govs}")
    lines.append(
        f"  CPUs online: {_cpus(p.online)}; isolated: {_cpus(p.isolated)}; "
        f"nohz_full: {_cpus(p.nohz_full)}"
    )
    where = f"CPU {cfg.cpu}" if cfg.cpu >= 0 else "not pinned ([step_thread] cpu = -1)"
    lines.append(f"  executor: {cfg.executor}, SCHED_FIFO {cfg.priority}, {where}")
    if p.undervoltage is None and p.throttled is None:
        lines.append("  under-voltage/throttling: not reported by this board")
    else:
        if p.undervoltage is not None:
            lines.append(
                "  under-voltage (rpi_volt): "
                + ("YES, in the last 2 s" if p.undervoltage else "no")
            )
        if p.throttled is not None:
            what = ", ".join(throttled_text(p.throttled)) or "nothing"
            lines.append(f"  firmware get_throttled: 0x{p.throttled:x} ({what})")
    if rt is not None:
        lines.append(
            "  real time as [step_thread] asks, tried by the probe as its user (the "
            "service's: motorctld --status):"
        )
        lines += realtime_lines(rt.as_dict(), 96, "    ", label="")
    if lat is None:
        lines.append(f"  latency: {skipped or 'not measured'}")
    else:
        lines.append(
            f"  latency: {lat.samples:,} timed sleeps of {INTERVAL_S * 1000:.0f} ms "
            f"at {lat.policy}: late p50 {lat.p50_us:,.0f} us, p99 "
            f"{lat.p99_us:,.0f} us, max {lat.max_us:,.0f} us"
        )
        lines.extend(f"    {note}" for note in lat.notes)
    tips = advice(p, lat, cfg, motors)
    lines.append("advice:" if tips else "advice: nothing to change")
    lines.extend(f"  - {tip}" for tip in tips)
    return "\n".join(lines) + "\n"
