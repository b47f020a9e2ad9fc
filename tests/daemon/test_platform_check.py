"""``motorctld --probe``'s platform check, from fake /proc and /sys trees (the kernel files a
Raspberry Pi, an RT board and a bare container show): the facts read, the advice given, the
lag arithmetic; the latency measurement with SCHED_FIFO refused (it says so and measures
anyway); the probe of a real daemon config end to end."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from motorctl.daemon.platform_check import (
    Latency,
    MotorRate,
    Roots,
    TimingConfig,
    advice,
    lag_full_steps,
    measure_latency,
    parse_cpulist,
    read_platform,
    report,
    throttled_text,
)
from tests.support import REPO
from tests.support.daemon_proc import StartDaemon, for_tests

ROOT = REPO


def tree(base: Path, files: dict[str, str]) -> Roots:
    for rel, text in files.items():
        path = base / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return Roots(proc=base / "proc", sys=base / "sys")


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
MOTORS = [MotorRate("x", 25_000.0, 16), MotorRate("y", 25_000.0, 16), MotorRate("z", 4_000.0, None)]


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
    mock = [MotorRate("x", 25_000.0, None, loses_steps=False)]
    assert "the mock's simulated motor x slide instead" in advice(p, late, cfg, mock)[-1]
    slow = [MotorRate("x", 3_000.0, 16), MotorRate("y", 25_000.0, 16, start_speed=30_000.0)]
    assert not any("beyond" in t for t in advice(p, late, cfg, slow))
    spun = Latency(samples=10, p50_us=10.0, p99_us=300.0, max_us=400.0, policy="x")
    assert "more than step_thread.spin_us (200)" in advice(p, spun, cfg, [])[0]
    assert "priority = 0" in advice(p, None, TimingConfig(cpu=3, priority=0), [])[0]


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
    assert lag_full_steps(200.0, 25_000, 16) == pytest.approx(0.3125)


def test_the_measurement_goes_on_without_sched_fifo() -> None:
    lat = measure_latency(0.05, 50, -1, realtime=lambda priority: "Operation not permitted")
    assert lat.samples > 0 and lat.max_us >= lat.p99_us >= lat.p50_us >= 0
    assert lat.policy == "normal priority"
    assert lat.notes == [
        "SCHED_FIFO 50 refused (Operation not permitted): measured at normal "
        "priority; run the probe as root, or as the service's user with its "
        "LimitRTPRIO, to measure what the executor gets"
    ]
    asked: list[int] = []

    def grant(priority: int) -> None:
        asked.append(priority)

    granted = measure_latency(0.02, 7, -1, realtime=grant)
    assert asked == [7] and granted.policy == "SCHED_FIFO 7" and not granted.notes


def test_probe_prints_the_platform_section(tmp_path: Path) -> None:
    """The real probe on this machine (no real-time priority in the test config)."""
    config = tmp_path / "m.toml"
    config.write_text(for_tests('[[motors]]\nname = "a"\nmax_speed = 20000\n'))
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.main",
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
    assert "max lag at 20,000 step/s with 16 microsteps would be" in text
    assert "Traceback" not in out.stderr


LAT0 = ("--latency-seconds", "0")


def _probe(tmp_path: Path, step_thread: str) -> subprocess.CompletedProcess[str]:
    config = tmp_path / "m.toml"
    config.write_text(
        for_tests(f'[step_thread]\n{step_thread}\n[[motors]]\nname = "a"\n', force=True)
    )
    return subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.main", "--probe", "--config", str(config), *LAT0],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def test_probe_says_which_step_core_would_run(tmp_path: Path) -> None:
    out = _probe(tmp_path, 'core = "auto"')
    assert out.returncode == 0, out.stderr
    assert (
        'step core:\n  [step_thread] core = "auto", executor = "process"\n'
        "  compiled core: built\n  lines for it: the simulated mechanics of the mock\n"
        "  runs: compiled\n"
    ) in out.stdout


def test_the_compiled_core_where_it_cannot_run_is_a_probe_problem_and_a_start_error(
    tmp_path: Path, motorctld: StartDaemon
) -> None:
    out = _probe(tmp_path, 'core = "compiled"\nexecutor = "thread"')
    assert out.returncode == 1
    assert "  runs: python (the thread executor runs the Python core)\n" in out.stdout
    assert 'PROBLEM: [step_thread] core = "compiled" runs in the process executor only' in (
        out.stdout
    )
    config = 'core = "compiled"\nexecutor = "thread"'
    text = for_tests(f'[step_thread]\n{config}\n[[motors]]\nname = "a"\n', force=True)
    with pytest.raises(RuntimeError, match="motorctld exited") as err:
        motorctld(text)
    assert '[step_thread] core = "compiled" runs in the process executor only' in str(err.value)
