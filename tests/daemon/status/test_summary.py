"""The status document as a person reads it (daemon/status/summary.py): an example document
summed up exactly as docs/status.md shows it (the doc's block is this test's output), each
real-time refusal with its reason and fix, a motor's last error read from whatever error
field it has, and documents of other daemons (older, newer, odd) shown as far as they go.
(``motorctld --status`` on a real terminal against a real daemon: tests/daemon/start/test_main.py
and tests/daemon/start/test_serve_realtime_e2e.py.)"""

from __future__ import annotations

from typing import Any

from motorctl.daemon.status.summary import summary
from tests.support import REPO

#: a daemon's document (the keys a real one has; figures made up): three motors, one of
#: them faulted with its last error answer, the kernel having refused SCHED_FIFO
EXAMPLE: dict[str, Any] = {
    "version": "0.2.0",
    "uptime_s": 3725.4,
    "motors": [
        {
            "index": 0,
            "name": "x",
            "state": "idle",
            "position": 1200,
            "speed": 0.0,
            "queued": 0,
            "fault": None,
            "position_lost": False,
        },
        {
            "index": 1,
            "name": "y",
            "state": "fault",
            "position": 0,
            "speed": 0.0,
            "queued": 0,
            "fault": "end stop hit",
            "position_lost": True,
            "last_error": {
                "code": "E4",
                "command": "MoveTo(motor=1, dir=down, pos=0, ...)",
                "reason": "end stop hit at 0 outside homing",
            },
        },
        {
            "index": 2,
            "name": "z",
            "state": "moving",
            "position": -310,
            "speed": -2000.0,
            "queued": 1,
            "fault": None,
            "position_lost": False,
        },
    ],
    "steps": {
        "steps": 123456,
        "p50_us": 4.0,
        "p99_us": 35.0,
        "max_us": 236.4,
        "late": 3,
        "late_threshold_us": 100.0,
        "timing_lost": 0,
        "segments_discarded": 24,
    },
    "executor": {
        "alive": True,
        "reason": None,
        "kind": "process",
        "core": "compiled",
        "pid": 812,
        "realtime": {
            "cpu_affinity": {
                "state": "granted",
                "what": "CPU 3",
                "error": None,
                "reason": None,
                "fix": None,
            },
            "memory_lock": {
                "state": "granted",
                "what": "mlockall",
                "error": None,
                "reason": None,
                "fix": None,
            },
            "sched_fifo": {
                "state": "refused",
                "what": "SCHED_FIFO 50",
                "error": "EPERM",
                "reason": "EPERM (Operation not permitted) although RLIMIT_RTPRIO 99 allows "
                "it: the kernel's RT group scheduling (CONFIG_RT_GROUP_SCHED) gives the "
                "process's cgroup /system.slice/motorctld.service no real-time time",
                "fix": "give that cgroup a real-time budget (cgroup v1: its cpu.rt_runtime_us, "
                "e.g. 950000, within kernel.sched_rt_runtime_us), or boot a kernel without "
                "CONFIG_RT_GROUP_SCHED (docs/raspberry-pi.md, 'Real time')",
            },
            "refused": ["sched_fifo"],
            "kernel": {"release": "6.12.75+rpt-rpi-v8", "preempt_rt": False},
        },
    },
    "link": {
        "counters": {
            "frames": 1234,
            "checksum_errors": 1,
            "length_errors": 0,
            "sent_E1": 1,
            "sent_E4": 2,
            "link_errors": 0,
        },
        "processing": {"reads": 1230, "p99_us": 68.0, "over_target": 10, "target_us": 108.0},
        "peer": "open",
        "device": "/dev/ttyAMA0",
    },
    "state": {"ok": True, "writes": 57},
    "pins": [
        {"number": 0, "output": True, "level": True},
        {"number": 1, "output": False, "level": False},
    ],
    "dc": {"state": "coast", "running": False, "left_s": None},
}


def doc_block() -> str:
    """docs/status.md's summary, the block after "On a terminal"."""
    text = (REPO / "docs" / "status.md").read_text()
    section = text.split("## On a terminal", 1)[1]
    return section.split("```\n", 2)[1]


def test_the_summary_in_docs_status_is_this_one() -> None:
    assert doc_block() == summary(EXAMPLE, 100)


def test_each_refusal_comes_with_its_reason_and_fix_and_the_motor_with_its_error() -> None:
    lines = summary(EXAMPLE, 100).splitlines()
    at = lines.index("real time: REFUSED, steps best effort")
    assert lines[at + 1].startswith("  SCHED_FIFO 50 REFUSED: EPERM (Operation not permitted)")
    assert any(line.startswith("    fix: give that cgroup a real-time budget") for line in lines)
    assert "  1 y: FAULT, position 0 (lost: home it), speed 0 step/s" in lines
    assert "      fault: end stop hit" in lines
    assert (
        "      last error: E4 on MoveTo(motor=1, dir=down, pos=0, ...) (end stop hit at 0 "
        "outside homing)"
    ) in lines
    assert max(map(len, lines)) <= 100 and len(lines) <= 24


def test_a_last_error_is_read_from_whatever_error_field_the_motor_has() -> None:
    def of(motor_extra: dict[str, Any]) -> str:
        motor = {"index": 0, "name": "x", "state": "idle", "position": 0, **motor_extra}
        return summary({"motors": [motor]})

    assert "last error: E2 invalid address" in of({"last_error": "E2 invalid address"})
    assert "last error: E1 on SetPin (pin 9 not configured)" in of(
        {"error": {"code": "E1", "command": "SetPin", "message": "pin 9 not configured"}}
    )
    assert "last error: kind stall, at_s 12.5" in of(
        {"last_error": {"kind": "stall", "at_s": 12.5}}
    )
    assert "last error" not in of({"last_error": None}) + of({"errors": 0})
    assert "last error" not in of({"errors": {"E4": 2}})  # counts, not an error
    link: dict[str, Any] = {"counters": {}, "processing": {}}
    frame = {"code": "E1", "reason": "checksum 0x12, expected 0x34"}
    assert "  last error of no motor: E1 (checksum 0x12, expected 0x34)" in summary(
        {"link": link, "errors": frame}
    )


def test_older_newer_and_odd_documents_show_what_they_have() -> None:
    empty = summary({})
    assert empty.startswith("motorctld ?, up ?: step executor ?, step core ?, DEAD: not running")
    assert "real time: not reported by this daemon" in empty
    assert "motors: none reported" in empty and "link: not serving" in empty
    assert "step timing: not reported" in empty
    ramp = summary({"executor": {"kind": "none", "alive": True}})
    assert "no step executor (every motor runs its driver's own ramp)" in ramp
    assert "real time: no step executor" in ramp
    odd = summary(
        {
            "motors": [None, {"index": "?", "position": "far"}],
            "steps": {"steps": "many"},
            "link": {"counters": 3, "processing": []},
            "executor": {"realtime": {"sched_fifo": "granted", "kernel": None}},
            "pins": {"0": 1},
        }
    )
    assert "  ? ?: ?, position ?, speed ? step/s" in odd and "real time: " in odd
    granted = summary(
        {
            "executor": {
                "realtime": {
                    k: {"state": "granted", "what": w}
                    for k, w in (
                        ("sched_fifo", "SCHED_FIFO 50"),
                        ("memory_lock", "mlockall"),
                        ("cpu_affinity", "CPU 3"),
                    )
                }
                | {"kernel": {"release": "6.12.62+rpt-rpi-v8-rt", "preempt_rt": True}}
            }
        },
        width=120,
    )
    assert (
        "real time: SCHED_FIFO 50 granted; mlockall granted; CPU 3 granted; kernel "
        "6.12.62+rpt-rpi-v8-rt PREEMPT_RT"
    ) in granted
