"""The metrics read from fixed places of the status document, as tables (docs/status.md,
"Metrics"): :data:`SCALARS` (one value each), :data:`MOTOR_FIELDS` (one per motor),
:data:`LINK_COUNTERS` (the link's counters under names of their own) and :data:`SUMMARIES`
(quantiles with their count and sum). A new status field is one line here;
daemon/status/metrics.py writes them (and the metrics that are not a fixed place: states,
pins, drivers) with prometheus_client.

Pure data: no import beyond the standard library; read by any thread.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Field:
    """One metric read from one place of the document: ``key`` a dotted path (from the
    document, or from a motor for :data:`MOTOR_FIELDS`), ``name`` without ``_total``, and
    the factor to base units."""

    key: str
    name: str
    kind: str  # "counter" or "gauge"
    help: str
    scale: float = 1.0


SCALARS: tuple[Field, ...] = (
    Field("steps.steps", "motorctl_steps", "counter", "Step edges made by the step executor."),
    Field("steps.late", "motorctl_steps_late", "counter", "Step edges later than the threshold."),
    Field(
        "steps.timing_lost",
        "motorctl_steps_timing_lost",
        "counter",
        "Motors stopped because a late step's lag was beyond the motor's max_lag_full_steps "
        "(E4 step timing lost).",
    ),
    Field(
        "steps.segments_discarded",
        "motorctl_step_segments_discarded",
        "counter",
        "Planned step segments the executor discarded unstepped because a re-plan or a stop "
        "replaced them (normal: not lost steps).",
    ),
    Field("steps.io_errors", "motorctl_step_io_errors", "counter", "STEP/DIR line errors."),
    Field("steps.endstops", "motorctl_step_endstops", "counter", "End-stop triggers acted on."),
    Field(
        "steps.bad_records",
        "motorctl_step_bad_records",
        "counter",
        "Records from the daemon the executor found bad (each a fault of its motor).",
    ),
    Field(
        "steps.ring_retries_reports",
        "motorctl_step_ring_retries_reports",
        "counter",
        "Retries reading the executor's report ring.",
    ),
    Field(
        "steps.ring_retries_segments",
        "motorctl_step_ring_retries_segments",
        "counter",
        "Retries writing the executor's segment ring.",
    ),
    Field("steps.progress", "motorctl_executor_progress", "counter", "Turns of the executor."),
    Field(
        "steps.max_us",
        "motorctl_step_lateness_max_seconds",
        "gauge",
        "The latest step edge since start.",
        1e-6,
    ),
    Field(
        "steps.late_threshold_us",
        "motorctl_step_late_threshold_seconds",
        "gauge",
        "A step edge later than this counts as late.",
        1e-6,
    ),
    Field(
        "steps.min_gap_ns",
        "motorctl_step_min_gap_seconds",
        "gauge",
        "The shortest gap between two step edges of one motor (0: none yet).",
        1e-9,
    ),
    Field("executor.alive", "motorctl_executor_alive", "gauge", "1 while the executor runs."),
    Field("link.held", "motorctl_link_held_frames", "gauge", "Frames held behind a WaitMoved."),
    Field("link.waiting", "motorctl_link_waiting", "gauge", "1 while a WaitMoved holds answers."),
    Field(
        "link.unsent_bytes",
        "motorctl_link_unsent_bytes",
        "gauge",
        "Answer bytes not yet taken by the port.",
    ),
    Field(
        "link.processing.max_us",
        "motorctl_link_processing_max_seconds",
        "gauge",
        "The longest processing since start.",
        1e-6,
    ),
    Field("state.ok", "motorctl_state_ok", "gauge", "1 while the state file is written fine."),
    Field("state.writes", "motorctl_state_writes", "counter", "State file writes."),
    Field("state.errors", "motorctl_state_write_errors", "counter", "State writes that failed."),
    Field(
        "state.save_errors",
        "motorctl_state_save_errors",
        "counter",
        "SaveHome/SaveWayPoint answered E4 because the state could not be written.",
    ),
    Field(
        "state.motion_refused",
        "motorctl_state_motion_refused",
        "counter",
        "Motion commands answered E4 because the motion journal could not be written.",
    ),
    Field(
        "state.last_write_ms",
        "motorctl_state_last_write_duration_seconds",
        "gauge",
        "How long the last state file write took.",
        1e-3,
    ),
    Field(
        "state.journal.marks",
        "motorctl_state_journal_marks",
        "counter",
        "Motions marked in the motion journal.",
    ),
    Field(
        "hard_stops.wait_max_us",
        "motorctl_hard_stop_wait_max_seconds",
        "gauge",
        "The longest a hard stop waited for the executor's confirmation.",
        1e-6,
    ),
    Field("trace.runs", "motorctl_trace_runs", "counter", "Byte runs the trace recorded."),
    Field(
        "trace.dropped_runs",
        "motorctl_trace_dropped_runs",
        "counter",
        "Byte runs left out of the trace (its writer fell behind).",
    ),
    Field(
        "trace.bytes_written",
        "motorctl_trace_written_bytes",
        "counter",
        "Bytes written to the trace files.",
    ),
    Field("trace.rotations", "motorctl_trace_rotations", "counter", "Trace file rotations."),
    Field(
        "trace.write_errors",
        "motorctl_trace_write_errors",
        "counter",
        "Trace writes that failed.",
    ),
    Field(
        "trace.lost_bytes",
        "motorctl_trace_lost_bytes",
        "counter",
        "Bytes lost to failed trace writes.",
    ),
    Field(
        "trace.max_file_bytes",
        "motorctl_trace_max_file_bytes",
        "gauge",
        "A trace file's size at which it rotates.",
    ),
    Field("trace.files", "motorctl_trace_files", "gauge", "Trace files kept, rotated ones too."),
)

#: each motor's values (labels motor, name)
MOTOR_FIELDS: tuple[Field, ...] = (
    Field("position", "motorctl_motor_position_steps", "gauge", "Position as the host sees it."),
    Field(
        "speed",
        "motorctl_motor_speed_steps_per_second",
        "gauge",
        "The motor's planned speed now (signed).",
    ),
    Field("position_lost", "motorctl_motor_position_lost", "gauge", "1 while it must be homed."),
    Field(
        "queued",
        "motorctl_motor_queued_commands",
        "gauge",
        "Motion commands queued behind the running one.",
    ),
    Field("waypoints", "motorctl_motor_waypoints", "gauge", "Waypoints saved for the motor."),
    Field(
        "timing.late_absorbed",
        "motorctl_motor_late_steps_absorbed",
        "counter",
        "Late steps absorbed by sliding the motor's schedule.",
    ),
    Field(
        "timing.slid_ms",
        "motorctl_motor_slid_seconds",
        "counter",
        "Time the motor's schedule slid to absorb late steps.",
        1e-3,
    ),
    Field(
        "timing.worst_late_us",
        "motorctl_motor_worst_lateness_seconds",
        "gauge",
        "The latest step of the motor, after its planned time.",
        1e-6,
    ),
    Field(
        "timing.worst_lag_full_steps",
        "motorctl_motor_worst_lag_full_steps",
        "gauge",
        "The motor's worst lag behind its plan, in full steps.",
    ),
    Field(
        "timing.lag_faults",
        "motorctl_motor_lag_faults",
        "counter",
        "Faults for a lag beyond the motor's limit.",
    ),
    Field("timing.microsteps", "motorctl_motor_microsteps", "gauge", "Microsteps per full step."),
    Field(
        "timing.max_lag_full_steps",
        "motorctl_motor_max_lag_full_steps",
        "gauge",
        "The lag, in full steps, beyond which the motor faults.",
    ),
)

#: link.counters read under a name of their own: key -> name, kind, help, labels
LINK_COUNTERS: dict[str, tuple[str, str, str, dict[str, str]]] = {
    **{
        f"{reason}_errors": (
            "motorctl_link_frame_errors",
            "counter",
            "Frames that failed their checks (answered E1), by reason.",
            {"reason": reason},
        )
        for reason in ("checksum", "unknown", "padding", "length")
    },
    **{
        f"sent_E{n}": (
            "motorctl_link_error_responses",
            "counter",
            "Error responses sent, by code.",
            {"code": f"E{n}"},
        )
        for n in range(7)
    },
    **{
        f"responses_dropped_{cause}": (
            "motorctl_link_responses_dropped",
            "counter",
            "Answers never sent, by cause (unsent, wait, held: owed to a host whose session "
            "ended; shutdown).",
            {"cause": cause},
        )
        for cause in ("unsent", "wait", "held", "shutdown")
    },
    "bytes_in": ("motorctl_link_received_bytes", "counter", "Bytes received from the host.", {}),
    "link_errors": (
        "motorctl_link_port_errors",
        "counter",
        "Read or write errors of the port (other than the host closing it).",
        {},
    ),
    "held_max": (
        "motorctl_link_held_frames_max",
        "gauge",
        "The most frames ever held behind a WaitMoved at once.",
        {},
    ),
    "link_timeouts": (
        "motorctl_link_timeouts",
        "counter",
        "Times the host fell silent for [link] timeout_ms with motors in motion.",
        {},
    ),
    "link_timeout_stops": (
        "motorctl_link_timeout_stops",
        "counter",
        "Motors stopped because the host fell silent ([link] timeout_ms).",
        {},
    ),
}


@dataclass(frozen=True)
class Summary:
    """A summary from one place of the document: quantiles ``p50_us``..., ``_count`` from
    ``count``, ``_sum`` from ``sum`` (each key within ``key``'s mapping)."""

    key: str
    name: str
    help: str
    count: str
    sum: str
    quantiles: tuple[tuple[str, str], ...]
    scale: float = 1e-6


SUMMARIES: tuple[Summary, ...] = (
    Summary(
        "steps",
        "motorctl_step_lateness_seconds",
        "How late step edges were, after their planned time (since start).",
        "steps",
        "sum_us",
        (("p50_us", "0.5"), ("p99_us", "0.99"), ("p999_us", "0.999")),
    ),
    Summary(
        "link.processing",
        "motorctl_link_processing_seconds",
        "From a read to its answers being written (since start).",
        "reads",
        "sum_us",
        (("p50_us", "0.5"), ("p99_us", "0.99"), ("p999_us", "0.999")),
    ),
    Summary(
        "hard_stops",
        "motorctl_hard_stop_wait_seconds",
        "How long hard stops waited for the executor's confirmation (quantiles over the "
        "latest 1024).",
        "waits",
        "wait_sum_us",
        (("wait_p50_us", "0.5"), ("wait_p99_us", "0.99")),
    ),
)
