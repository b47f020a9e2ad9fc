"""``motorctld --status --format prometheus|openmetrics`` from documents, written by
prometheus_client: each format parsed by prometheus_client's parser of that format (the
Prometheus text format 0.0.4, which node_exporter's textfile collector reads; OpenMetrics,
strictly), every counter typed counter in both, summaries with ``_count`` and ``_sum``, no
quantile on a gauge, the build's version, the trace's state, the renamed metrics of issue
27, names and base units, nothing but ``motorctl_up`` (and the version) from an empty
document; promtool's lint (``promtool check metrics``'s rules, tests/support/promlint.py, on
prometheus_client's parser) on the Prometheus format, and promtool itself where it is
installed: ``make test`` never installs it (it comes with Debian's whole ``prometheus``
server package); ``make test-deb`` runs it on the installed package's timer output. Against a
live daemon: tests/daemon/status/test_document_e2e.py; read by Debian's node_exporter: make
test-deb (tests/deb/check-install.sh)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from typing import Any

import pytest
from prometheus_client.metrics_core import Metric
from prometheus_client.openmetrics.parser import text_string_to_metric_families as _om
from prometheus_client.parser import text_string_to_metric_families as _prometheus

from motorctl.daemon.status.metric_tables import LINK_COUNTERS, MOTOR_FIELDS, SCALARS
from motorctl.daemon.status.metrics import down, metrics
from tests.support import REPO
from tests.support.promlint import lint

DOC: dict[str, Any] = {
    "version": "9.8.7",
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
        "sum_us": 7500.0,
        "late": 3,
        "late_threshold_us": 100.0,
        "timing_lost": 2,
        "min_gap_ns": 479635,
        "segments_discarded": 0,
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
            "link_timeouts": 1,
            "link_timeout_stops": 2,
        },
        "processing": {
            "reads": 9,
            "p50_us": 20.0,
            "p99_us": 40.0,
            "p999_us": 41.0,
            "max_us": 44.0,
            "sum_us": 230.0,
        },
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
        "waits": 2,
        "wait_p50_us": 100.0,
        "wait_p99_us": 200.0,
        "wait_max_us": 250.0,
        "wait_sum_us": 350.0,
    },
    "trace": {
        "file": "/run/motorctl/link.pcapng",
        "runs": 120,
        "dropped_runs": 3,
        "bytes_written": 4096,
        "rotations": 1,
        "write_errors": 2,
        "lost_bytes": 64,
        "max_file_bytes": 16777216,
        "files": 4,
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


Samples = dict[tuple[str, frozenset[tuple[str, str]]], float]


def samples(families: list[Metric]) -> Samples:
    return {(s.name, frozenset(s.labels.items())): s.value for f in families for s in f.samples}


def counters() -> set[str]:
    """Every counter the tables name (family names, without _total)."""
    names = {f.name for f in (*SCALARS, *MOTOR_FIELDS) if f.kind == "counter"}
    names |= {name for name, kind, _, _ in LINK_COUNTERS.values() if kind == "counter"}
    return names | {
        "motorctl_motor_faults",
        "motorctl_hard_stops",
        "motorctl_clamped_values",
        "motorctl_driver_polls",
        "motorctl_driver_spi_errors",
        "motorctl_driver_faults",
        "motorctl_link_frames",
        "motorctl_link_responses",
    }


@pytest.mark.parametrize("fmt", ["prometheus", "openmetrics"])
def test_every_counter_is_typed_counter_and_summaries_have_count_and_sum(fmt: str) -> None:
    text = metrics(DOC, fmt)
    families = parse_prometheus(text) if fmt == "prometheus" else parse_om(text)
    types = {f.name: f.type for f in families}
    assert all(name.startswith("motorctl_") for name in types)
    present = counters() & set(types)
    assert present >= {"motorctl_steps", "motorctl_link_frames", "motorctl_trace_runs"}
    assert {name: types[name] for name in present} == dict.fromkeys(present, "counter")
    assert "untyped" not in types.values() and "unknown" not in types.values()
    for f in families:
        if f.type == "counter":
            assert {s.name for s in f.samples} == {f.name + "_total"}, f.name
        if f.type == "summary":
            names = {s.name for s in f.samples}
            assert {f.name + "_count", f.name + "_sum"} <= names, f.name
        if f.type != "summary":  # quantiles only on summaries
            assert all("quantile" not in s.labels for s in f.samples), f.name
    assert types["motorctl_hard_stop_wait_seconds"] == "summary"
    assert types["motorctl_build" if fmt == "openmetrics" else "motorctl_build_info"] == (
        "info" if fmt == "openmetrics" else "gauge"
    )
    if fmt == "openmetrics":
        assert text.endswith("# EOF\n")
        assert "# UNIT motorctl_step_lateness_seconds seconds" in text


def test_names_values_and_base_units() -> None:
    got = samples(parse_prometheus(metrics(DOC)))
    x = frozenset({("motor", "0"), ("name", 'we"ird\\name')})  # escaped, read back whole
    none: frozenset[tuple[str, str]] = frozenset()
    assert got[("motorctl_build_info", frozenset({("version", "9.8.7")}))] == 1
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
    assert got[("motorctl_steps_total", none)] == 1000
    assert got[("motorctl_step_lateness_seconds", frozenset({("quantile", "0.99")}))] == 31e-6
    assert got[("motorctl_step_lateness_seconds_count", none)] == 1000
    assert got[("motorctl_step_lateness_seconds_sum", none)] == 0.0075
    assert got[("motorctl_link_processing_seconds_sum", none)] == 0.00023
    assert got[("motorctl_link_processing_seconds_count", none)] == 9
    assert got[("motorctl_hard_stop_wait_seconds", frozenset({("quantile", "0.5")}))] == 1e-4
    assert got[("motorctl_hard_stop_wait_seconds_count", none)] == 2
    assert got[("motorctl_hard_stop_wait_seconds_sum", none)] == 0.00035
    assert got[("motorctl_hard_stop_wait_max_seconds", none)] == 0.00025
    assert got[("motorctl_step_min_gap_seconds", none)] == 479635e-9
    assert got[("motorctl_link_frame_errors_total", frozenset({("reason", "checksum")}))] == 1
    assert got[("motorctl_link_error_responses_total", frozenset({("code", "E2")}))] == 4
    assert got[("motorctl_link_received_bytes_total", none)] == 100
    assert got[("motorctl_link_held_frames_max", none)] == 3
    assert got[("motorctl_link_peer_open", none)] == 1
    dropped = "motorctl_link_responses_dropped_total"
    assert got[(dropped, frozenset({("cause", "held")}))] == 2
    assert (dropped, none) not in got  # the total: the sum of the causes
    assert got[("motorctl_state_ok", none)] == 0
    assert got[("motorctl_start_time_seconds", none)] == 1_700_000_000.0
    assert got[("motorctl_pin_level", frozenset({("pin", "3"), ("mode", "output")}))] == 1
    assert not any(
        name == "motorctl_pin_level" and ("pin", "4") in labels for name, labels in got
    )  # unreadable: left out, not a 0
    assert got[("motorctl_dc_state", frozenset({("state", "forward")}))] == 1
    assert got[("motorctl_dc_run_left_seconds", none)] == 0.25
    dev = frozenset({("device", "/dev/spidev0.0"), ("chip", "TMC5160")})
    assert got[("motorctl_driver_faults_total", dev | {("flag", "ot")})] == 1


def test_the_renamed_metrics_of_issue_27_and_the_trace_state() -> None:
    got = samples(parse_prometheus(metrics(DOC)))
    names = {name for name, _ in got}
    none: frozenset[tuple[str, str]] = frozenset()
    assert got[("motorctl_link_timeouts_total", none)] == 1
    assert got[("motorctl_link_timeout_stops_total", none)] == 2
    assert got[("motorctl_state_last_write_duration_seconds", none)] == 0.0015
    assert (
        not {
            "motorctl_link_link_timeouts_total",
            "motorctl_link_link_timeout_stops_total",
            "motorctl_state_last_write_seconds",
        }
        & names
    )
    assert got[("motorctl_trace_enabled", none)] == 1
    assert got[("motorctl_trace_runs_total", none)] == 120
    assert got[("motorctl_trace_dropped_runs_total", none)] == 3
    assert got[("motorctl_trace_written_bytes_total", none)] == 4096
    assert got[("motorctl_trace_rotations_total", none)] == 1
    assert got[("motorctl_trace_write_errors_total", none)] == 2
    assert got[("motorctl_trace_lost_bytes_total", none)] == 64
    untraced = samples(parse_prometheus(metrics({k: v for k, v in DOC.items() if k != "trace"})))
    assert untraced[("motorctl_trace_enabled", none)] == 0
    assert not any(name.startswith("motorctl_trace_runs") for name, _ in untraced)


def test_the_renamed_metrics_of_issue_35() -> None:
    """Discarded planned segments are not dropped steps: the counter says so, under its new
    name only; the processing summary counts reads."""
    doc = {**DOC, "steps": {**DOC["steps"], "segments_discarded": 24}}
    got = samples(parse_prometheus(metrics(doc)))
    none: frozenset[tuple[str, str]] = frozenset()
    assert got[("motorctl_step_segments_discarded_total", none)] == 24
    assert not any(name.startswith("motorctl_steps_dropped") for name, _ in got)
    assert got[("motorctl_link_processing_seconds_count", none)] == 9


def test_the_chips_of_a_dspin_chain_are_told_apart_by_their_position() -> None:
    """Two chips of one model on one chain share device and chip: their place tells them
    apart (else the series would be one sample written twice, which a scrape refuses)."""
    chip = {"chip": "L6470", "device": "/dev/spidev0.0", "polls": 3, "spi_errors": 0}
    chain = [
        {**chip, "chain_position": 0, "fault_counts": {"OCD": 2}, "warning_counts": {}},
        {**chip, "chain_position": 1, "fault_counts": {"OCD": 1}, "warning_counts": {}},
    ]
    text = metrics({**DOC, "drivers": chain})
    assert lint(text) == []
    got = samples(parse_prometheus(text))
    who = {("device", "/dev/spidev0.0"), ("chip", "L6470"), ("flag", "OCD")}
    assert got[("motorctl_driver_faults_total", frozenset(who | {("chain_position", "0")}))] == 2
    assert got[("motorctl_driver_faults_total", frozenset(who | {("chain_position", "1")}))] == 1


def test_what_is_missing_is_left_out() -> None:
    none: frozenset[tuple[str, str]] = frozenset()
    up, enabled = ("motorctl_up", none), ("motorctl_trace_enabled", none)
    assert samples(parse_om(metrics({}, "openmetrics"))) == {up: 1, enabled: 0}
    odd = {
        "motors": [None, {"index": 0, "state": "warping"}],
        "steps": "no",
        "link": 3,
        "pins": {"0": 1},
        "dc": None,
        "hard_stops": {"wait_p50_us": 3.0},  # no count and sum: no summary at all
    }
    got = samples(parse_om(metrics(odd, "openmetrics")))
    assert got[("motorctl_motor_state", frozenset({("motor", "0"), ("state", "warping")}))] == 1
    assert not any(name.startswith("motorctl_hard_stop_wait") for name, _ in got)
    for fmt in ("prometheus", "openmetrics"):
        parse = parse_prometheus if fmt == "prometheus" else parse_om
        assert samples(parse(down(fmt))) == {up: 0}


EXPOSITIONS = {"document": metrics(DOC), "empty": metrics({}), "down": down()}


@pytest.mark.parametrize("which", EXPOSITIONS)
def test_promtools_lint_passes(which: str) -> None:
    """promtool's rules (tests/support/promlint.py) on what node_exporter reads."""
    assert lint(EXPOSITIONS[which]) == []


# Expositions promtool refuses (checked against Debian 12's promtool 2.42), with what the lint
# says of each: the lint can fail, and fails where promtool does.
MALFORMED = {
    '# HELP x h\n# TYPE x gauge\nx{a="1} 1\n': "text format parsing error",
    "# HELP x h\n# TYPE x gauge\nx 1 abc\n": "text format parsing error",
    "# TYPE x gauge\nx 1\n": "x no help text",
    "# HELP x h\n# TYPE x counter\nx 1\n": 'x counter metrics should have "_total" suffix',
    "# HELP x_total h\n# TYPE x_total gauge\nx_total 1\n": "x_total non-counter metrics should",
    "# HELP x h\n# TYPE x counter\nx_total 1\n# HELP x h\n# TYPE x counter\nx_total 2\n": (
        "x has 2 HELP lines"
    ),
    "# HELP fooBar h\n# TYPE fooBar gauge\nfooBar 1\n": "fooBar metric names should be written",
    '# HELP x h\n# TYPE x gauge\nx{fooBar="1"} 1\n': "x label names should be written",
    "# HELP x:y h\n# TYPE x:y gauge\nx:y 1\n": "x:y metric names should not contain ':'",
    "# HELP x_ms h\n# TYPE x_ms gauge\nx_ms 1\n": "x_ms metric names should not contain abbre",
    "# HELP x_sec_total h\n# TYPE x_sec_total counter\nx_sec_total 1\n": (
        "x_sec_total metric names should not contain abbreviated units"
    ),
    "# HELP x_hours h\n# TYPE x_hours gauge\nx_hours 1\n": 'x_hours use base unit "seconds"',
    "# HELP x_kilobytes h\n# TYPE x_kilobytes gauge\nx_kilobytes 1\n": "x_kilobytes use base unit",
    "# HELP x_count h\n# TYPE x_count gauge\nx_count 1\n": "x_count non-histogram and non-summ",
    "# HELP x_bucket h\n# TYPE x_bucket gauge\nx_bucket 1\n": "x_bucket non-histogram metrics",
    '# HELP x h\n# TYPE x gauge\nx{le="1"} 1\n': 'x non-histogram metrics should not have "le"',
    '# HELP x h\n# TYPE x gauge\nx{quantile="1"} 1\n': "x non-summary metrics should not",
    "# HELP x_gauge h\n# TYPE x_gauge untyped\nx_gauge 1\n": "x_gauge metric name should not",
    "# HELP x_counter_total h\n# TYPE x_counter_total counter\nx_counter_total 1\n": (
        "x_counter_total metric name should not include type 'counter'"
    ),
}


@pytest.mark.parametrize("text", MALFORMED)
def test_the_lint_finds_what_promtool_finds(text: str) -> None:
    problems = lint(text)
    assert any(problem.startswith(MALFORMED[text]) for problem in problems), problems
    promtool = shutil.which("promtool")
    if promtool is not None:  # the same verdict as promtool's, where it is installed
        run = subprocess.run(
            [promtool, "check", "metrics"], input=text, capture_output=True, text=True, timeout=60
        )
        assert run.returncode != 0, run.stdout + run.stderr


def test_the_lint_is_stricter_than_promtool_where_a_scrape_is() -> None:
    """A family or a series given twice passes promtool 2.42; a scrape refuses it."""
    again = "# HELP x h\n# TYPE x gauge\nx 1\n# HELP y h\n# TYPE y gauge\ny 1\nx 2\n"
    assert "x is given in more than one place" in lint(again)
    twice = '# HELP x h\n# TYPE x gauge\nx{a="1"} 1\nx{a="1"} 2\n'
    assert "x{'a': '1'} is given twice" in lint(twice)
    good = '# HELP x h\n# TYPE x summary\nx{quantile="0.5"} 1\nx_sum 1\nx_count 1\n'
    assert lint(good) == []


def test_promtool_check_metrics_passes() -> None:
    """promtool's own lint of what node_exporter reads (the Prometheus format), where promtool
    is installed; make test-deb runs it on the installed package's timer output."""
    promtool = shutil.which("promtool")
    if promtool is None:
        pytest.skip(
            "promtool is not installed (make test never installs Debian's prometheus server "
            "package for it): its rules are checked by tests/support/promlint.py, promtool "
            "itself by make test-deb"
        )
    for text in EXPOSITIONS.values():
        run = subprocess.run(
            [promtool, "check", "metrics"], input=text, capture_output=True, text=True, timeout=60
        )
        assert run.returncode == 0 and run.stdout + run.stderr == "", run.stdout + run.stderr


def test_without_prometheus_client_the_status_says_what_to_install(tmp_path: Any) -> None:
    code = (
        "import sys; sys.modules['prometheus_client'] = None\n"
        "from motorctl.daemon.start.main import main\n"
        f"sys.exit(main(['--status', '--format', 'prometheus', '--state-dir', {str(tmp_path)!r}]))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert run.returncode == 2 and run.stdout == ""
    assert "apt install python3-prometheus-client" in run.stderr
    assert "pip install motorctl[metrics]" in run.stderr and "Traceback" not in run.stderr
