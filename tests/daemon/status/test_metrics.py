"""``motorctld --status --format openmetrics`` from documents: valid OpenMetrics
(prometheus_client's strict parser) that node_exporter's Prometheus text parser also reads
(only counter, gauge and summary types), names and units, the per-motor timing figures of
issue 15 when present, nothing but ``motorctl_up`` from an empty document. Against a live
daemon: tests/daemon/status/test_document_e2e.py."""

from __future__ import annotations

from typing import Any

from prometheus_client.metrics_core import Metric
from prometheus_client.openmetrics.parser import text_string_to_metric_families as _om
from prometheus_client.parser import text_string_to_metric_families as _prometheus

from motorctl.daemon.status.metrics import down, openmetrics

DOC: dict[str, Any] = {
    "uptime_s": 100.0,
    "unix_s": 1_700_000_100.0,
    "monotonic_s": 5.0,
    "motors": [
        {
            "index": 0,
            "name": 'we"ird\\name',
            "state": "fault",
            "position": -12,
            "speed": -250.5,
            "queued": 1,
            "fault": "step timing lost",
            "position_lost": True,
            "waypoints": 2,
            "faults": {"timing_lost": 2, "endstop": 1},
            "timing": {
                "late_absorbed": 40,
                "slid_ms": 12.5,
                "worst_late_us": 850.0,
                "worst_lag_full_steps": 1.25,
                "lag_faults": 2,
                "microsteps": 16,
                "max_lag_full_steps": 2.0,
            },
        },
        {
            "index": 1,
            "name": "y",
            "state": "idle",
            "position": 0,
            "speed": 0.0,
            "queued": 0,
            "fault": None,
            "position_lost": False,
            "waypoints": 0,
        },
    ],
    "steps": {
        "steps": 1000,
        "p50_us": 7.0,
        "p99_us": 31.0,
        "p999_us": 63.0,
        "max_us": 90.5,
        "late": 3,
        "late_threshold_us": 100.0,
        "timing_lost": 2,
        "min_gap_ns": 479635,
        "dropped": 0,
        "io_errors": 0,
        "endstops": 1,
        "progress": 55,
    },
    "executor": {"alive": True, "kind": "process", "core": "compiled", "pid": 12, "reason": None},
    "link": {
        "counters": {
            "bytes_in": 100,
            "frames": 10,
            "checksum_errors": 1,
            "sent_E2": 4,
            "held_max": 3,
            "link_errors": 0,
            "responses": 10,
            "responses_dropped": 3,
            "responses_dropped_wait": 1,
            "responses_dropped_held": 2,
        },
        "processing": {"steps": 9, "p50_us": 20.0, "p99_us": 40.0, "p999_us": 41.0, "max_us": 44.0},
        "held": 0,
        "waiting": False,
        "peer": "open",
        "unsent_bytes": 0,
        "recent": [],
    },
    "state": {
        "ok": False,
        "writes": 5,
        "errors": 1,
        "save_errors": 0,
        "motion_refused": 0,
        "last_write_ms": 1.5,
        "journal": {"marks": 3},
    },
    "hard_stops": {
        "confirmed": 2,
        "timed_out": 0,
        "skipped": 0,
        "died": 0,
        "wait_p50_us": 100.0,
        "wait_p99_us": 200.0,
        "wait_max_us": 250.0,
    },
    "clamped": {"speed": 2},
    "pins": [
        {"number": 3, "output": True, "level": True},
        {"number": 4, "output": False, "level": None, "error": "gone"},
    ],
    "dc": {"state": "forward", "running": True, "left_s": 0.25},
    "drivers": [
        {
            "chip": "TMC5160",
            "device": "/dev/spidev0.0",
            "polls": 7,
            "spi_errors": 1,
            "fault_counts": {"ot": 1},
            "warning_counts": {},
            "drv_status": "0x0",
        }
    ],
}


def parse_om(text: str) -> list[Metric]:
    """prometheus_client's OpenMetrics parser (strict: raises on anything invalid)."""
    return list(_om(text))  # type: ignore[no-untyped-call]


def parse_prometheus(text: str) -> list[Metric]:
    """prometheus_client's parser of the Prometheus text format (node_exporter's format)."""
    return list(_prometheus(text))


def samples(text: str) -> dict[tuple[str, frozenset[tuple[str, str]]], float]:
    return {
        (s.name, frozenset(s.labels.items())): s.value
        for family in parse_om(text)
        for s in family.samples
    }


def test_a_full_document_is_valid_openmetrics_with_base_units() -> None:
    text = openmetrics(DOC)
    assert text.endswith("# EOF\n")
    families = list(parse_om(text))
    assert {f.type for f in families} <= {"counter", "gauge", "summary"}
    assert all(f.name.startswith("motorctl_") for f in families)
    for f in families:
        if f.type == "counter":
            assert all(s.name == f.name + "_total" for s in f.samples), f.name
    got = samples(text)
    x = frozenset({("motor", "0"), ("name", 'we"ird\\name')})  # escaped, read back whole
    assert got[("motorctl_motor_position_steps", x)] == -12
    assert got[("motorctl_motor_speed_steps_per_second", x)] == -250.5
    assert got[("motorctl_motor_state", x | {("state", "fault")})] == 1
    assert got[("motorctl_motor_state", x | {("state", "idle")})] == 0
    assert got[("motorctl_motor_faulted", x)] == 1
    assert got[("motorctl_motor_faults_total", x | {("cause", "timing_lost")})] == 2
    assert got[("motorctl_motor_slid_seconds_total", x)] == 0.0125
    assert got[("motorctl_motor_worst_lateness_seconds", x)] == 0.00085
    assert got[("motorctl_motor_worst_lag_full_steps", x)] == 1.25
    assert got[("motorctl_motor_lag_faults_total", x)] == 2
    assert got[("motorctl_motor_max_lag_full_steps", x)] == 2.0
    assert got[("motorctl_motor_late_steps_absorbed_total", x)] == 40
    y = frozenset({("motor", "1"), ("name", "y")})
    assert ("motorctl_motor_slid_seconds_total", y) not in got  # no timing for y: none
    assert got[("motorctl_steps_total", frozenset())] == 1000
    assert got[("motorctl_step_lateness_seconds", frozenset({("quantile", "0.99")}))] == 31e-6
    assert got[("motorctl_step_lateness_seconds_count", frozenset())] == 1000
    assert got[("motorctl_step_min_gap_seconds", frozenset())] == 479635e-9
    assert got[("motorctl_link_frame_errors_total", frozenset({("reason", "checksum")}))] == 1
    assert got[("motorctl_link_error_responses_total", frozenset({("code", "E2")}))] == 4
    assert got[("motorctl_link_received_bytes_total", frozenset())] == 100
    assert got[("motorctl_link_held_frames_max", frozenset())] == 3
    assert got[("motorctl_link_peer_open", frozenset())] == 1
    dropped = "motorctl_link_responses_dropped_total"
    assert got[(dropped, frozenset({("cause", "held")}))] == 2
    assert (dropped, frozenset()) not in got  # the total: the sum of the causes
    assert got[("motorctl_state_ok", frozenset())] == 0
    assert got[("motorctl_start_time_seconds", frozenset())] == 1_700_000_000.0
    assert got[("motorctl_pin_level", frozenset({("pin", "3"), ("mode", "output")}))] == 1
    assert not any(
        name == "motorctl_pin_level" and ("pin", "4") in labels for name, labels in got
    )  # unreadable: left out, not a 0
    assert got[("motorctl_dc_state", frozenset({("state", "forward")}))] == 1
    assert got[("motorctl_dc_run_left_seconds", frozenset())] == 0.25
    dev = frozenset({("device", "/dev/spidev0.0"), ("chip", "TMC5160")})
    assert got[("motorctl_driver_faults_total", dev | {("flag", "ot")})] == 1
    assert "# UNIT motorctl_step_lateness_seconds seconds" in text
    # node_exporter's textfile collector reads the Prometheus text format: it must parse
    # there too (counters come out untyped under their _total names, values the same)
    prom = {s.name for f in parse_prometheus(text) for s in f.samples}
    assert {
        "motorctl_steps_total",
        "motorctl_motor_position_steps",
        "motorctl_step_lateness_seconds_count",
    } <= prom


def test_what_is_missing_is_left_out() -> None:
    assert samples(openmetrics({})) == {("motorctl_up", frozenset()): 1}
    odd = {
        "motors": [None, {"index": 0, "state": "warping"}],
        "steps": "no",
        "link": 3,
        "pins": {"0": 1},
        "dc": None,
    }
    got = samples(openmetrics(odd))
    assert got[("motorctl_motor_state", frozenset({("motor", "0"), ("state", "warping")}))] == 1
    assert samples(down("no daemon")) == {("motorctl_up", frozenset()): 0}
