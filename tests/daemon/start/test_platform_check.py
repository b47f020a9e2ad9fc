"""``motorctld --probe``'s platform check, from fake /proc and /sys trees (the kernel files a
Raspberry Pi, an RT board and a bare container show): the facts read, the advice given, the
lag arithmetic; the latency measurement with SCHED_FIFO refused (it says so and measures
anyway); the probe of a real daemon config end to end."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from motorctl.daemon.start.platform_check import (
    Latency,
    Platform,
    Roots,
    TimingConfig,
    advice,
    measure_latency,
    parse_cpulist,
    read_platform,
    report,
    throttled_text,
)
from motorctl.motion.executors.base import lag_full_steps
from motorctl.motion.rt import GRANTED, NOT_ASKED, Outcome, RealtimeOptions, RealtimeReport
from tests.support import REPO
from tests.support.daemon_proc import for_tests
from tests.support.motor_defaults import motor_rate

ROOT = REPO


def tree(base: Path, files: dict[str, str]) -> Roots:
    for rel, text in files.items():
        path = base / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return Roots(proc=base / "proc", sys=base / "sys", etc=base / "etc")


#: a Raspberry Pi 4 on a stock kernel, unhappy power supply, nothing tuned
PI = {
    "proc/sys/kernel/osrelease": "6.6.31+rpt-rpi-v8\n",
    "proc/sys/kernel/version": "#1 SMP PREEMPT Debian 1:6.6.31-1+rpt1 (2024-05-29)\n",
    "proc/sys/kernel/sched_rt_runtime_us": "950000\n",
    "proc/sys/kernel/sched_rt_period_us": "1000000\n",
    "proc/cmdline": "console=serial0,115200 root=PARTUUID=1234-02 rootwait\n",
    "proc/device-tree/model": "Raspberry Pi 4 Model B Rev 1.5\x00",
    "sys/devices/system/cpu/online": "0-3\n",
    "sys/devices/system/cpu/isolated": "\n",
    **{f"sys/devices/system/cpu/cpu{c}/cpufreq/scaling_governor": "ondemand\n" for c in range(4)},
    "sys/class/hwmon/hwmon0/name": "cpu_thermal\n",
    "sys/class/hwmon/hwmon1/name": "rpi_volt\n",
    "sys/class/hwmon/hwmon1/in0_lcrit_alarm": "1\n",
    "sys/devices/platform/soc/soc:firmware/get_throttled": "50005\n",
}

#: an RT kernel, CPU 3 isolated for the executor, governor performance, throttling off
RT = {
    "proc/sys/kernel/osrelease": "6.1.0-21-rt-arm64\n",
    "proc/sys/kernel/version": "#1 SMP PREEMPT_RT Debian 6.1.90-1 (2024-05-03)\n",
    "proc/sys/kernel/sched_rt_runtime_us": "-1\n",
    "proc/cmdline": "isolcpus=3 nohz_full=3 quiet\n",
    "sys/kernel/realtime": "1\n",
    "sys/devices/system/cpu/online": "0-3\n",
    "sys/devices/system/cpu/isolated": "3\n",
    "sys/devices/system/cpu/nohz_full": "3\n",
    **{
        f"sys/devices/system/cpu/cpu{c}/cpufreq/scaling_governor": "performance\n" for c in range(4)
    },
    "sys/class/hwmon/hwmon1/name": "rpi_volt\n",
    "sys/class/hwmon/hwmon1/in0_lcrit_alarm": "0\n",
}

LATENCY = Latency(
    samples=3000, p50_us=12.0, p99_us=45.0, max_us=160.0, policy="SCHED_FIFO 50 on CPU 3"
)
MOTORS = [
    motor_rate("x", 25_000.0, 16),
    motor_rate("y", 25_000.0, 16),
    motor_rate("z", 4_000.0, None),
]


def test_a_raspberry_pi_on_a_stock_kernel(tmp_path: Path) -> None:
    p = read_platform(tree(tmp_path, PI))
    assert p.model == "Raspberry Pi 4 Model B Rev 1.5"
    assert p.kernel == "6.6.31+rpt-rpi-v8" and not p.rt and p.preempt == "full (PREEMPT)"
    assert (p.rt_runtime_us, p.rt_period_us) == (950_000, 1_000_000)
    assert p.online == {0, 1, 2, 3} and p.isolated == set()
    assert p.governors == dict.fromkeys(range(4), "ondemand")
    assert p.undervoltage is True and p.throttled == 0x50005
    tips = advice(p, LATENCY, TimingConfig(), MOTORS)
    assert tips[0].startswith("the board reports under-voltage or throttling")
    assert any(t.startswith("the kernel is not PREEMPT_RT") for t in tips)
    assert any("parked 50 ms of every 1000 ms" in t and "sched_rt_runtime_us=-1" in t for t in tips)
    assert any(t.startswith("cpufreq governor ondemand: set 'performance'") for t in tips)
    assert (
        "isolate a CPU for the executor (e.g. isolcpus=3 nohz_full=3 on the kernel "
        "command line, then [step_thread] cpu = 3)" in tips
    )
    # 160 us x 25,000 step/s / 16 = 0.25 full steps; x and y alike share a line
    assert (
        "max lag at 25,000 step/s with 16 microsteps would be 0.25 full steps (4.0 steps) "
        "after the worst wake-up (motors x, y)" in tips
    )
    assert (
        "max lag at 4,000 step/s with 16 microsteps would be 0.04 full steps (0.6 steps) "
        "after the worst wake-up (motor z; microsteps not in the config: 16 assumed)" in tips
    )
    text = report(p, LATENCY, TimingConfig(), MOTORS)
    assert "  board: Raspberry Pi 4 Model B Rev 1.5" in text
    assert "under-voltage (rpi_volt): YES, in the last 2 s" in text
    assert (
        "firmware get_throttled: 0x50005 (under-voltage now, throttled now, under-voltage "
        "has occurred, throttling has occurred)" in text
    )
    assert (
        "latency: 3,000 timed sleeps of 1 ms at SCHED_FIFO 50 on CPU 3: late p50 12 us, "
        "p99 45 us, max 160 us" in text
    )
    assert text.splitlines()[-len(tips) - 1] == "advice:"


#: the Pi of ``PI`` on Raspberry Pi OS trixie's stock kernel (as recorded on one)
PI_TRIXIE = {
    **PI,
    "proc/sys/kernel/osrelease": "6.12.75+rpt-rpi-v8\n",
    "proc/sys/kernel/version": "#1 SMP PREEMPT Debian 1:6.12.75-1+rpt1 (2026-03-11)\n",
    "sys/class/hwmon/hwmon1/in0_lcrit_alarm": "0\n",
    "sys/devices/platform/soc/soc:firmware/get_throttled": "0\n",
    "etc/os-release": 'PRETTY_NAME="Debian GNU/Linux 13 (trixie)"\nID=debian\n'
    "VERSION_CODENAME=trixie\n",
}


def test_the_probe_example_in_docs_timing_is_what_the_probe_prints(tmp_path: Path) -> None:
    """docs/timing.md's example: the report of the fake trixie Pi above, its real time
    granted (the probe run as root) and the figures of ``LATENCY``, exactly."""
    p = read_platform(tree(tmp_path, PI_TRIXIE), machine="aarch64")
    rt = RealtimeReport(
        Outcome(NOT_ASKED, "[step_thread] cpu = -1"),
        Outcome(GRANTED, "mlockall"),
        Outcome(GRANTED, "SCHED_FIFO 50"),
        "6.12.75+rpt-rpi-v8",
        False,
    )
    lat = Latency(2950, 14.0, 38.0, 160.0, "SCHED_FIFO 50")
    text = report(p, lat, TimingConfig(), MOTORS[:2], rt=rt)
    doc = (REPO / "docs" / "timing.md").read_text()
    block = doc.split("## Checking a platform", 1)[1].split("```\n", 2)[1]
    assert block.split("measuring timer wake-ups for 3 s ...\n", 1)[1] == text


def test_a_tuned_rt_board_needs_nothing_but_the_lag_figures(tmp_path: Path) -> None:
    p = read_platform(tree(tmp_path, RT))
    assert p.rt and p.preempt == "PREEMPT_RT" and p.rt_runtime_us == -1
    assert p.isolated == {3} and p.nohz_full == {3} and p.undervoltage is False
    cfg = TimingConfig(cpu=3)
    tips = advice(p, LATENCY, cfg, MOTORS[:1])
    assert tips == [
        "max lag at 25,000 step/s with 16 microsteps would be 0.25 full steps "
        "(4.0 steps) after the worst wake-up (motor x)"
    ]
    assert advice(p, None, cfg, MOTORS) == []
    assert "advice: nothing to change" in report(p, None, cfg, MOTORS, "not measured")
    text = report(p, None, cfg, MOTORS, "not measured")
    assert "kernel.sched_rt_runtime_us: -1 (no RT throttling)" in text
    assert "cpufreq governor: performance (CPU 0,1,2,3)" in text
    assert "CPUs online: 0,1,2,3; isolated: 3; nohz_full: 3" in text
    assert "under-voltage (rpi_volt): no" in text
    # the executor's CPU not isolated, not online; a late worst case; no real-time priority
    assert advice(p, None, TimingConfig(cpu=2), [])[0].startswith(
        "the executor's CPU 2 is not isolated: add isolcpus=2"
    )
    assert "is not an online CPU (0,1,2,3)" in advice(p, None, TimingConfig(cpu=7), [])[0]
    # a worst wake-up of 2.5 ms: 2.5 full steps at 25,000 step/s, beyond the tolerance; safe
    # up to 0.5 x 16 / 2.5 ms = 3,200 step/s; z (4,000 step/s, 0.62 full steps) too
    late = Latency(samples=10, p50_us=10.0, p99_us=100.0, max_us=2500.0, policy="x")
    tips = advice(p, late, cfg, MOTORS)
    assert (
        "that is beyond max_lag_full_steps (0.5): a wake-up that late stops motors x, y "
        "with E4 'step timing lost' above 3,200 step/s; make the platform steadier (above) "
        "or keep them slower" in tips
    )
    assert sum("beyond max_lag_full_steps" in t for t in tips) == 2
    mock = [motor_rate("x", 25_000.0, None, loses_steps=False)]
    assert "the mock's simulated motor x slide instead" in advice(p, late, cfg, mock)[-1]
    slow = [motor_rate("x", 3_000.0, 16), motor_rate("y", 25_000.0, 16, start_speed=30_000.0)]
    assert not any("beyond" in t for t in advice(p, late, cfg, slow))
    spun = Latency(samples=10, p50_us=10.0, p99_us=300.0, max_us=400.0, policy="x")
    assert "more than step_thread.spin_us (200)" in advice(p, spun, cfg, [])[0]
    assert "priority = 0" in advice(p, None, TimingConfig(cpu=3, priority=0), [])[0]


#: ``uname -r`` and ``uname -v`` as recorded on real machines, and whether each is PREEMPT_RT
#: (its /sys/kernel/realtime: the RT patch set's flag, which mainline PREEMPT_RT lacks)
KERNELS = [
    # mainline PREEMPT_RT (6.12 on): Debian trixie's rt flavour, no /sys/kernel/realtime
    ("6.12.43+deb13-rt-amd64", "#1 SMP PREEMPT_RT Debian 6.12.43-1 (2025-08-27)", None, True),
    # Raspberry Pi OS trixie's linux-image-rpi-v8-rt (mainline RT: no flag either)
    ("6.12.62+rpt-rpi-v8-rt", "#1 SMP PREEMPT_RT Debian 1:6.12.62-1+rpt1 (2025-12-18)", None, True),
    # Debian bookworm's -rt kernel (the RT patch set: its flag is there)
    ("6.1.0-18-rt-amd64", "#1 SMP PREEMPT_RT Debian 6.1.76-1 (2024-02-01)", "1", True),
    # Debian buster's -rt kernel: the RT patch set of 4.19 wrote "PREEMPT RT"
    ("4.19.0-23-rt-amd64", "#1 SMP PREEMPT RT Debian 4.19.269-1 (2022-12-20)", None, True),
    # Raspberry Pi OS's stock kernels: full preemption, not RT
    ("6.6.31+rpt-rpi-v8", "#1 SMP PREEMPT Debian 1:6.6.31-1+rpt1 (2024-05-29)", None, False),
    ("6.12.75+rpt-rpi-v8", "#1 SMP PREEMPT Debian 1:6.12.75-1+rpt1 (2026-03-11)", None, False),
    # Debian's generic kernel
    ("6.12.43+deb13-amd64", "#1 SMP PREEMPT_DYNAMIC Debian 6.12.43-1 (2025-08-27)", None, False),
]


@pytest.mark.parametrize(("release", "version", "flag", "rt"), KERNELS, ids=[k[0] for k in KERNELS])
def test_preempt_rt_is_read_from_the_kernel_version_too(
    tmp_path: Path, release: str, version: str, flag: str | None, rt: bool
) -> None:
    files = {"proc/sys/kernel/osrelease": f"{release}\n", "proc/sys/kernel/version": version}
    if flag is not None:
        files["sys/kernel/realtime"] = f"{flag}\n"
    p = read_platform(tree(tmp_path, files), machine="x86_64")
    assert p.kernel == release and p.rt is rt
    tips = advice(p, None, TimingConfig(cpu=1), [])
    assert any(t.startswith("the kernel is not PREEMPT_RT") for t in tips) is not rt


def test_a_raspberry_pi_is_told_the_way_to_an_rt_kernel_on_its_os_release(tmp_path: Path) -> None:
    """A Pi 5 on Raspberry Pi OS trixie's stock kernel: the package, the config.txt line,
    as docs/raspberry-pi.md says (its model from /sys/firmware/devicetree here)."""
    files = {
        "proc/sys/kernel/osrelease": "6.12.47+rpt-rpi-2712\n",
        "proc/sys/kernel/version": "#1 SMP PREEMPT Debian 1:6.12.47-1+rpt1 (2025-09-16)\n",
        "sys/firmware/devicetree/base/model": "Raspberry Pi 5 Model B Rev 1.0\x00",
        "etc/os-release": 'PRETTY_NAME="Debian GNU/Linux 13 (trixie)"\nID=debian\n'
        "VERSION_CODENAME=trixie\n",
    }
    p = read_platform(tree(tmp_path, files), machine="aarch64")
    assert p.model == "Raspberry Pi 5 Model B Rev 1.0" and not p.rt
    tip = next(t for t in advice(p, None, TimingConfig(cpu=3), []) if "PREEMPT_RT" in t)
    assert tip.startswith(
        "the kernel is not PREEMPT_RT, which bounds the executor's wake-ups: Raspberry Pi 5 "
        "Model B Rev 1.0, Raspberry Pi OS trixie: 'sudo apt install linux-image-rpi-v8-rt', "
        "then 'kernel=kernel8_rt.img' in /boot/firmware/config.txt and reboot; on a Pi 5 too"
    )
    assert tip.endswith("; docs/raspberry-pi.md, 'A real-time kernel'")


def test_a_bare_tree_reports_what_it_cannot_see(tmp_path: Path) -> None:
    p = read_platform(Roots(proc=tmp_path / "none", sys=tmp_path / "none"))
    assert p.kernel is None and p.preempt == "unknown" and p.governors == {}
    text = report(p, None, TimingConfig(), [], "skipped")
    assert "board: not reported" in text and "not readable" in text
    assert "no cpufreq" in text and "not reported by this board" in text
    assert "latency: skipped" in text
    dynamic = read_platform(
        tree(
            tmp_path / "dyn",
            {
                "proc/sys/kernel/version": "#1 SMP PREEMPT_DYNAMIC Debian\n",
                "sys/kernel/debug/sched/preempt": "none voluntary (full) lazy\n",
            },
        )
    )
    assert dynamic.preempt == "full (PREEMPT_DYNAMIC)"
    cmdline = read_platform(
        tree(
            tmp_path / "cmd",
            {
                "proc/sys/kernel/version": "#1 SMP PREEMPT_DYNAMIC Debian\n",
                "proc/cmdline": "preempt=voluntary isolcpus=1-2\n",
            },
        )
    )
    assert cmdline.preempt == "voluntary (PREEMPT_DYNAMIC)" and cmdline.isolated == {1, 2}


def test_an_unreadable_preemption_mode_says_what_to_do(tmp_path: Path) -> None:
    """PREEMPT_DYNAMIC without preempt= on the command line: the mode is in debugfs."""
    version = {"proc/sys/kernel/version": "#1 SMP PREEMPT_DYNAMIC Debian\n"}
    user = read_platform(tree(tmp_path / "user", version), euid=1000)
    assert "needs root and debugfs: run --probe as root" in user.preempt
    unmounted = read_platform(tree(tmp_path / "root", version), euid=0)
    assert "root" not in unmounted.preempt.split("debugfs is not mounted")[0]
    assert "debugfs is not mounted: 'mount -t debugfs none /sys/kernel/debug'" in unmounted.preempt
    base = tmp_path / "mounted"
    mounts = f"sysfs {base}/sys sysfs rw 0 0\ndebugfs {base}/sys/kernel/debug debugfs rw 0 0\n"
    mounted = read_platform(tree(base, {**version, "proc/mounts": mounts}), euid=0)
    assert "CONFIG_SCHED_DEBUG" in mounted.preempt and "mount" not in mounted.preempt


def test_small_parsers() -> None:
    assert parse_cpulist("0-2,5\n") == {0, 1, 2, 5} and parse_cpulist("") == set()
    assert parse_cpulist("junk,3") == {3}
    assert throttled_text(0x80008) == [
        "soft temperature limit now",
        "soft temperature limit has occurred",
    ]
    assert throttled_text(1 << 30) == ["bit 30 (unknown)"]
    assert lag_full_steps(200e-6, 1 / 25_000, 16) == pytest.approx(0.3125)


def test_the_measurement_goes_on_without_sched_fifo(monkeypatch: pytest.MonkeyPatch) -> None:
    """SCHED_FIFO refused (the kernel's EPERM, injected at os.sched_setscheduler): the
    probe says so, with the reason, and measures at normal priority."""

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    got, lat = measure_latency(0.05, RealtimeOptions(priority=50, lock_memory=False))
    assert got.sched_fifo.state == "refused" and got.sched_fifo.error == "EPERM"
    assert got.memory_lock.state == got.cpu_affinity.state == "not asked"
    assert lat is not None and lat.samples > 0 and lat.max_us >= lat.p99_us >= lat.p50_us >= 0
    assert lat.policy == "normal priority"
    assert lat.notes == [
        "SCHED_FIFO 50 refused (see 'real time' above): measured at normal priority"
    ]
    asked: list[int] = []

    def grant(pid: int, policy: int, param: os.sched_param) -> None:
        asked.append(param.sched_priority)

    monkeypatch.setattr(os, "sched_setscheduler", grant)
    got, granted = measure_latency(0.02, RealtimeOptions(priority=7, lock_memory=False))
    assert asked == [7] and got.sched_fifo.state == "granted"
    assert granted is not None and granted.policy == "SCHED_FIFO 7" and not granted.notes
    got, none = measure_latency(0, RealtimeOptions(priority=7, lock_memory=False))
    assert none is None and got.sched_fifo.state == "granted"  # asked, not measured


def test_the_probe_shows_what_real_time_it_got(monkeypatch: pytest.MonkeyPatch) -> None:
    """The report's real-time lines: a refusal with its reason and its fix."""

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    got, _ = measure_latency(0, RealtimeOptions(priority=50, lock_memory=False))
    text = report(Platform(), None, TimingConfig(), [], "skipped", got)
    assert "  real time as [step_thread] asks, tried by the probe as its user (" in text
    assert "\n    REFUSED, steps best effort\n" in text
    assert "      SCHED_FIFO 50 REFUSED: EPERM (Operation not permitted)" in text
    assert "\n        fix: " in text and "CPU pinning not asked" in text


def test_probe_prints_the_platform_section(tmp_path: Path) -> None:
    """The real probe on this machine (no real-time priority in the test config)."""
    config = tmp_path / "m.toml"
    config.write_text(for_tests('[[motors]]\nname = "a"\nmax_speed = 20000\n'))
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--probe",
            "--config",
            str(config),
            "--latency-seconds",
            "0.2",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert "platform (what decides step timing):" in text
    assert "latency: " in text and "timed sleeps of 1 ms at normal priority" in text
    assert "[step_thread] priority = 0" in text
    assert "SCHED_FIFO not asked ([step_thread] priority = 0)" in text  # what it would get
    assert "max lag at 20,000 step/s with 16 microsteps would be" in text
    assert "Traceback" not in out.stderr
