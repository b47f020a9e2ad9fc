"""Real time and what it got (motion/rt.py): each request granted, refused with the
kernel's error, its reason and the fix, or not asked; refusals made by the kernel for real
where a test can make it refuse (a CPU that is not there), else injected at the syscall's
own API (os.sched_setscheduler raising PermissionError, as a kernel without the limit or
with RT group scheduling answers); why each refusal happened, read from the limits and
capabilities; the report across a process boundary and in one line; the kernel's
preemption model from ``uname -v``."""

from __future__ import annotations

import errno
import logging
import os
from dataclasses import replace

import pytest

from motorctl.motion.rt import (
    GRANTED,
    NOT_ASKED,
    REFUSED,
    Outcome,
    Privileges,
    RealtimeOptions,
    RealtimeReport,
    cpu_refused,
    enter_realtime,
    fifo_refused,
    kernel_preempt_rt,
    memory_refused,
    read_privileges,
)
from tests.support import REPO

EPERM = PermissionError(errno.EPERM, "Operation not permitted")


def refuse(pid: int, policy: int, param: os.sched_param) -> None:
    raise EPERM


def test_sched_fifo_refused_by_the_kernel_is_reported_with_why_and_the_fix(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    limited = Privileges(rtprio_limit=0, cpus=frozenset({0, 1}))
    with caplog.at_level(logging.WARNING, "motorctl.rt"):
        got = enter_realtime(RealtimeOptions(50, False, -1), "the step thread", lambda: limited)
    assert got.refused() == ["sched_fifo"]
    fifo = got.sched_fifo
    assert (fifo.state, fifo.what, fifo.error) == (REFUSED, "SCHED_FIFO 50", "EPERM")
    assert fifo.reason == (
        "EPERM (Operation not permitted): RLIMIT_RTPRIO is 0, below 50, and the process "
        "lacks CAP_SYS_NICE"
    )
    assert fifo.fix is not None and "LimitRTPRIO=50 or more" in fifo.fix
    assert got.memory_lock == Outcome(NOT_ASKED, "[step_thread] lock_memory = false")
    assert got.cpu_affinity == Outcome(NOT_ASKED, "[step_thread] cpu = -1")
    assert got.kernel == os.uname().release
    # one warning in the log, with the reason and the fix
    assert [r.getMessage() for r in caplog.records] == [
        f"SCHED_FIFO 50 refused for the step thread: {fifo.reason}; {fifo.fix}"
    ]


def test_a_cpu_that_is_not_there_is_refused_by_the_kernel() -> None:
    """A real refusal: no machine has CPU 1023 online (the config's largest)."""
    got = enter_realtime(RealtimeOptions(0, False, 1023), "a test thread")
    cpu = got.cpu_affinity
    assert (cpu.state, cpu.what, cpu.error) == (REFUSED, "CPU 1023", "EINVAL")
    allowed = ",".join(str(c) for c in sorted(os.sched_getaffinity(0)))
    assert cpu.fix == f"[step_thread] cpu = one of {allowed}, or -1 to not pin"
    assert got.sched_fifo.state == got.memory_lock.state == NOT_ASKED


def test_what_was_granted_is_said_granted(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[int] = []
    monkeypatch.setattr(
        os, "sched_setscheduler", lambda pid, policy, param: asked.append(param.sched_priority)
    )
    before = os.sched_getaffinity(0)
    cpu = min(before)
    got = enter_realtime(RealtimeOptions(7, False, cpu), "a test thread")
    try:
        assert asked == [7] and got.refused() == []
        assert got.sched_fifo == Outcome(GRANTED, "SCHED_FIFO 7")
        assert got.cpu_affinity == Outcome(GRANTED, f"CPU {cpu}")
        assert os.sched_getaffinity(0) == {cpu}
    finally:
        os.sched_setaffinity(0, before)


# ---------------------------------------------------------------- why, and the fix


def test_sched_fifo_refused_although_the_limits_allow_it_is_rt_group_scheduling() -> None:
    """The machine of issue 35: EPERM with LimitRTPRIO=99 (or as root): the kernel's RT
    group scheduling gives the service's cgroup no real-time time."""
    for p in (
        Privileges(rtprio_limit=99, cgroup="/system.slice/motorctld.service"),
        Privileges(cap_sys_nice=True, cgroup="/system.slice/motorctld.service"),
    ):
        got = fifo_refused(EPERM, 50, p)
        assert got.error == "EPERM" and got.reason is not None and got.fix is not None
        assert "allows it: the kernel's RT group scheduling (CONFIG_RT_GROUP_SCHED)" in got.reason
        assert "cgroup /system.slice/motorctld.service no real-time time" in got.reason
        assert "cpu.rt_runtime_us" in got.fix and "without CONFIG_RT_GROUP_SCHED" in got.fix
    no_time = fifo_refused(EPERM, 50, Privileges(rtprio_limit=99, rt_runtime_us=0))
    assert no_time.reason is not None and "kernel.sched_rt_runtime_us is 0" in no_time.reason
    assert no_time.fix is not None and no_time.fix.startswith("sysctl kernel.sched_rt_runtime_us")
    bad = fifo_refused(OSError(errno.EINVAL, "Invalid argument"), 120, Privileges())
    assert (bad.error, bad.fix) == ("EINVAL", "[step_thread] priority: 1..99, or 0 to not ask")


def test_mlockall_and_cpu_refusals_say_why() -> None:
    enomem = OSError(errno.ENOMEM, "Cannot allocate memory")
    got = memory_refused(enomem, Privileges(memlock_limit=8 << 20))
    assert got.reason == (
        "ENOMEM (Cannot allocate memory): RLIMIT_MEMLOCK is 8192 KiB, less than the process "
        "takes, and the process lacks CAP_IPC_LOCK"
    )
    assert got.fix is not None and "LimitMEMLOCK=infinity" in got.fix
    assert memory_refused(enomem, Privileges(cap_ipc_lock=True)).reason == (
        "ENOMEM (Cannot allocate memory)"
    )
    cpu = cpu_refused(OSError(errno.EINVAL, "Invalid argument"), 3, Privileges(cpus=frozenset()))
    assert cpu.fix == "[step_thread] cpu = one of none, or -1 to not pin"


def test_the_privileges_are_this_processs() -> None:
    p = read_privileges()
    assert p.cpus == frozenset(os.sched_getaffinity(0))
    root = os.geteuid() == 0
    assert not root or p.cap_sys_nice or p.rtprio_limit is None or p.rtprio_limit >= 0


# ---------------------------------------------------------------- the report


REPORT = RealtimeReport(
    Outcome(GRANTED, "CPU 3"),
    Outcome(REFUSED, "mlockall", "ENOMEM", "ENOMEM (Cannot allocate memory): ...", "fix it"),
    Outcome(REFUSED, "SCHED_FIFO 50", "EPERM", "EPERM (Operation not permitted): ...", "fix"),
    "6.12.47+rpt-rpi-v8",
    False,
)


def test_the_report_crosses_as_a_document_and_back() -> None:
    doc = REPORT.as_dict()
    assert doc["refused"] == ["memory_lock", "sched_fifo"]
    assert doc["kernel"] == {"release": "6.12.47+rpt-rpi-v8", "preempt_rt": False}
    assert doc["cpu_affinity"] == {
        "state": "granted",
        "what": "CPU 3",
        "error": None,
        "reason": None,
        "fix": None,
    }
    assert RealtimeReport.from_dict(doc) == REPORT
    for bad in ({}, {"sched_fifo": 3}, None, "text"):
        with pytest.raises(ValueError, match="not a real-time report"):
            RealtimeReport.from_dict(bad)


def test_the_report_in_one_line() -> None:
    assert REPORT.words() == (
        "real time SCHED_FIFO 50 REFUSED (EPERM), mlockall REFUSED (ENOMEM), CPU 3, kernel "
        "not PREEMPT_RT: steps best effort, 'motorctld --status' says why and the fix"
    )
    granted = RealtimeReport(
        Outcome(NOT_ASKED, "[step_thread] cpu = -1"),
        Outcome(GRANTED, "mlockall"),
        Outcome(GRANTED, "SCHED_FIFO 50"),
        "6.12.62+rpt-rpi-v8-rt",
        True,
    )
    assert granted.words() == "real time SCHED_FIFO 50, memory locked, PREEMPT_RT kernel"
    assert "; " not in REPORT.words() + granted.words()  # one field of the READY line
    nothing = RealtimeReport(
        Outcome(NOT_ASKED, "[step_thread] cpu = -1"),
        Outcome(NOT_ASKED, "[step_thread] lock_memory = false"),
        Outcome(NOT_ASKED, "[step_thread] priority = 0"),
    )
    assert nothing.words() == (
        "real time not asked ([step_thread] cpu = -1, lock_memory = false, priority = 0)"
    )


def test_the_docs_quote_the_report_as_it_reads() -> None:
    """The READY line's real-time field as docs/timing.md and docs/raspberry-pi.md quote
    it (their line breaks aside): each quote is the words of a report."""
    default = RealtimeReport(  # the embedded default, granted
        Outcome(NOT_ASKED, "[step_thread] cpu = -1"),
        Outcome(GRANTED, "mlockall"),
        Outcome(GRANTED, "SCHED_FIFO 50"),
    )
    refused = replace(default, memory_lock=REPORT.memory_lock, sched_fifo=REPORT.sched_fifo)
    fifo_only = replace(default, sched_fifo=REPORT.sched_fifo)
    nothing = RealtimeReport(
        Outcome(NOT_ASKED, "[step_thread] cpu = -1"),
        Outcome(NOT_ASKED, "[step_thread] lock_memory = false"),
        Outcome(NOT_ASKED, "[step_thread] priority = 0"),
    )
    pages = {
        "timing.md": (default, refused, nothing),
        "raspberry-pi.md": (default, fifo_only),
    }
    for page, reports in pages.items():
        text = " ".join((REPO / "docs" / page).read_text().split())
        for report in reports:
            assert f"{report.words()}`" in text, (page, report.words())
    readme = (REPO / "README.md").read_text()
    assert f"; {refused.words()}\n" in readme


# ---------------------------------------------------------------- the kernel


@pytest.mark.parametrize(
    ("version", "flag", "rt"),
    [
        # mainline PREEMPT_RT (6.12 on: Debian 13's rt flavour) has no /sys/kernel/realtime
        ("#1 SMP PREEMPT_RT Debian 6.12.43-1 (2025-08-27)", None, True),
        # Raspberry Pi OS trixie's linux-image-rpi-v8-rt
        ("#1 SMP PREEMPT_RT Debian 1:6.12.62-1+rpt1 (2025-12-18)", None, True),
        # Debian 12's -rt kernel (the RT patch set; its flag too)
        ("#1 SMP PREEMPT_RT Debian 6.1.76-1 (2024-02-01)", "1\n", True),
        # Debian 10's -rt kernel: the RT patch set of 4.19 wrote it in two words
        ("#1 SMP PREEMPT RT Debian 4.19.269-1 (2022-12-20)", None, True),
        # NixOS's
        ("#1-NixOS SMP PREEMPT_RT Tue Jan  1 00:00:00 UTC 1980", None, True),
        # Raspberry Pi OS's stock kernel; Debian's generic one
        ("#1 SMP PREEMPT Debian 1:6.6.31-1+rpt1 (2024-05-29)", None, False),
        ("#1 SMP PREEMPT_DYNAMIC Debian 6.12.43-1 (2025-08-27)", None, False),
        # only the flag says so
        ("#1 SMP PREEMPT", "1", True),
        ("#1 SMP PREEMPT", "0\n", False),
        ("", None, False),
    ],
)
def test_preempt_rt_from_the_version_or_the_flag(version: str, flag: str | None, rt: bool) -> None:
    assert kernel_preempt_rt(version, flag) is rt
