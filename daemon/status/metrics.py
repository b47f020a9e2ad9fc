"""The status document as metrics: the OpenMetrics text format (``motorctld --status --format
openmetrics``), for node_exporter's textfile collector (docs/service.md, "Metrics").

Pure: a status document in, text out; no socket, no clock. Every name starts with
``motorctl_``, values are in base units (seconds, bytes; steps are the machine's own unit),
counters end in ``_total``. Only the counter, gauge and summary types are used, and no
timestamps: node_exporter's textfile collector reads the file with the Prometheus text
parser, which knows no other types (``info`` and ``stateset`` would make it drop the whole
file); what would be a stateset is a gauge with a ``state`` label, 1 for the current state.
Fields are read defensively: a field the document lacks (an older or newer daemon, per-motor
timing figures before issue 15) is left out, never an error.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from motorctl.hal.interfaces import BridgeState
from motorctl.motion.types import MotorState

Labels = Mapping[str, object]

#: link counters read under a name of their own (the rest: motorctl_link_<key>_total)
_FRAME_ERRORS = {
    "checksum_errors": "checksum",
    "unknown_errors": "unknown",
    "padding_errors": "padding",
    "length_errors": "length",
}
_LINK_RENAMED = {
    "bytes_in": ("motorctl_link_received_bytes", "Bytes received from the host.", "bytes"),
    "link_errors": (
        "motorctl_link_port_errors",
        "Read or write errors of the port (other than the host closing it).",
        None,
    ),
}
_LINK_GAUGES = {
    "held_max": (
        "motorctl_link_held_frames_max",
        "The most frames ever held behind a WaitMoved at once.",
    )
}
#: steps.* keys that are counters: name, help
_STEP_COUNTERS = {
    "steps": ("motorctl_steps", "Step edges made by the step executor."),
    "late": ("motorctl_steps_late", "Step edges later than the late threshold."),
    "timing_lost": (
        "motorctl_steps_timing_lost",
        "Motors stopped because a late step's lag was beyond the motor's "
        "max_lag_full_steps (E4 step timing lost).",
    ),
    "dropped": ("motorctl_steps_dropped", "Steps the executor dropped."),
    "io_errors": ("motorctl_step_io_errors", "STEP/DIR line errors in the executor."),
    "endstops": ("motorctl_step_endstops", "End-stop triggers the executor acted on."),
    "bad_records": (
        "motorctl_step_bad_records",
        "Records from the daemon the executor found bad (each a fault of its motor).",
    ),
    "ring_retries_reports": (
        "motorctl_step_ring_retries_reports",
        "Retries reading the executor's report ring.",
    ),
    "ring_retries_segments": (
        "motorctl_step_ring_retries_segments",
        "Retries writing the executor's segment ring.",
    ),
    "progress": ("motorctl_executor_progress", "Turns of the step executor's loop."),
}
#: per-motor timing figures (issue 15), when the daemon reports them: key -> name, type,
#: help, scale to base units
_TIMING = {
    "late_absorbed": (
        "motorctl_motor_late_steps_absorbed",
        "counter",
        "Late steps absorbed by sliding the motor's schedule.",
        1.0,
    ),
    "slid_ms": (
        "motorctl_motor_slid_seconds",
        "counter",
        "Time the motor's schedule slid to absorb late steps.",
        1e-3,
    ),
    "worst_late_us": (
        "motorctl_motor_worst_lateness_seconds",
        "gauge",
        "The latest step of the motor, after its planned time.",
        1e-6,
    ),
    "worst_lag_full_steps": (
        "motorctl_motor_worst_lag_full_steps",
        "gauge",
        "The motor's worst lag behind its plan, in full steps.",
        1.0,
    ),
    "lag_faults": (
        "motorctl_motor_lag_faults",
        "counter",
        "Faults for a lag beyond the motor's limit.",
        1.0,
    ),
    "microsteps": (
        "motorctl_motor_microsteps",
        "gauge",
        "Microsteps per full step of the motor.",
        1.0,
    ),
    "max_lag_full_steps": (
        "motorctl_motor_max_lag_full_steps",
        "gauge",
        "The lag, in full steps, beyond which the motor faults.",
        1.0,
    ),
}
_QUANTILES = (("p50_us", "0.5"), ("p99_us", "0.99"), ("p999_us", "0.999"))


@dataclass
class _Family:
    kind: str
    help: str
    unit: str | None
    samples: list[tuple[str, dict[str, str], float | int]] = field(default_factory=list)


class _Writer:
    """Families in the order first named; each family's samples together."""

    def __init__(self) -> None:
        self.families: dict[str, _Family] = {}

    def add(
        self,
        name: str,
        kind: str,
        help_text: str,
        value: object,
        labels: Labels | None = None,
        suffix: str = "",
        unit: str | None = None,
    ) -> None:
        number = _number(value)
        if number is None:
            return
        family = self.families.get(name)
        if family is None:
            family = self.families[name] = _Family(kind, help_text, unit)
        elif family.kind != kind:  # a programming error: one name, one type
            raise ValueError(f"{name} is a {family.kind}, not a {kind}")
        if kind == "counter":
            suffix = suffix or "_total"
        text_labels = {k: str(v) for k, v in (labels or {}).items() if v is not None}
        family.samples.append((name + suffix, text_labels, number))

    def gauge(
        self,
        name: str,
        help_text: str,
        value: object,
        labels: Labels | None = None,
        unit: str | None = None,
    ) -> None:
        self.add(name, "gauge", help_text, value, labels, unit=unit)

    def counter(
        self,
        name: str,
        help_text: str,
        value: object,
        labels: Labels | None = None,
        unit: str | None = None,
    ) -> None:
        self.add(name, "counter", help_text, value, labels, unit=unit)

    def summary(
        self,
        name: str,
        help_text: str,
        figures: Mapping[str, Any],
        count: object,
        scale: float,
        labels: Labels | None = None,
    ) -> None:
        """Quantiles ``p50_us``... of ``figures`` (scaled to seconds) and their count."""
        if not isinstance(figures, Mapping) or _number(count) is None:
            return
        for key, q in _QUANTILES:
            value = _number(figures.get(key))
            if value is not None:
                self.add(
                    name,
                    "summary",
                    help_text,
                    value * scale,
                    {**(labels or {}), "quantile": q},
                    unit="seconds",
                )
        self.add(name, "summary", help_text, count, labels, suffix="_count", unit="seconds")

    def text(self) -> str:
        out: list[str] = []
        for name, family in self.families.items():
            out.append(f"# TYPE {name} {family.kind}")
            if family.unit:
                out.append(f"# UNIT {name} {family.unit}")
            out.append(f"# HELP {name} {_escape_help(family.help)}")
            for sample, labels, value in family.samples:
                out.append(f"{sample}{_labels(labels)} {_value(value)}")
        out.append("# EOF")
        return "\n".join(out) + "\n"


def _number(value: object) -> float | int | None:
    """A sample's value: bools as 0/1, numbers as they are; None (absent, text, NaN)."""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return value
    if isinstance(value, float) and not math.isnan(value):
        return value
    return None


def _value(value: float | int) -> str:
    if isinstance(value, int):
        return str(value)
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    return repr(value)


def _escape_label(text: str) -> str:
    return text.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _escape_help(text: str) -> str:
    return text.replace("\\", "\\\\").replace("\n", "\\n")


def _labels(labels: Mapping[str, str]) -> str:
    if not labels:
        return ""
    return "{" + ",".join(f'{k}="{_escape_label(v)}"' for k, v in labels.items()) + "}"


def _dict(value: object) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _list(value: object) -> Iterable[Any]:
    return value if isinstance(value, list) else []


def openmetrics(doc: Mapping[str, Any]) -> str:
    """The status document ``doc`` (``motorctld --status``) in the OpenMetrics text format."""
    w = _Writer()
    w.gauge("motorctl_up", "1: the status was read from a running motorctld.", 1)
    unix, uptime = _number(doc.get("unix_s")), _number(doc.get("uptime_s"))
    if unix is not None and uptime is not None:
        w.gauge(
            "motorctl_start_time_seconds",
            "When motorctld started (Unix time).",
            round(unix - uptime, 3),
            unit="seconds",
        )
    _motors(w, doc)
    _steps(w, _dict(doc.get("steps")))
    _executor(w, _dict(doc.get("executor")))
    _link(w, doc.get("link"))
    _state(w, _dict(doc.get("state")))
    _hard_stops(w, _dict(doc.get("hard_stops")))
    for what, count in sorted(_dict(doc.get("clamped")).items()):
        w.counter(
            "motorctl_clamped_values",
            "Command values clamped to the motor's limits.",
            count,
            {"value": what},
        )
    _pins_and_dc(w, doc)
    _drivers(w, doc.get("drivers"))
    return w.text()


def down(reason: str) -> str:
    """The metrics when the daemon could not be read: ``motorctl_up 0`` (``reason`` is for
    the caller's stderr; node_exporter keeps no text)."""
    w = _Writer()
    w.gauge("motorctl_up", "1: the status was read from a running motorctld.", 0)
    return w.text()


def _motors(w: _Writer, doc: Mapping[str, Any]) -> None:
    states = [s.value for s in MotorState]
    for m in _list(doc.get("motors")):
        if not isinstance(m, Mapping):
            continue
        who = {"motor": m.get("index"), "name": m.get("name")}
        w.gauge(
            "motorctl_motor_position_steps",
            "The motor's position as the host sees it.",
            m.get("position"),
            who,
        )
        w.gauge(
            "motorctl_motor_speed_steps_per_second",
            "The motor's planned speed now (signed).",
            m.get("speed"),
            who,
        )
        state = m.get("state")
        for s in [*states, *([state] if isinstance(state, str) and state not in states else [])]:
            w.gauge(
                "motorctl_motor_state",
                "1 for the motor's current state.",
                int(s == state),
                {**who, "state": s},
            )
        if "fault" in m:
            w.gauge(
                "motorctl_motor_faulted",
                "1 while the motor has a latched fault (E4).",
                m.get("fault") is not None,
                who,
            )
        w.gauge(
            "motorctl_motor_position_lost",
            "1 while the motor must be homed again.",
            m.get("position_lost"),
            who,
        )
        w.gauge(
            "motorctl_motor_queued_commands",
            "Motion commands queued behind the running one.",
            m.get("queued"),
            who,
        )
        w.gauge(
            "motorctl_motor_waypoints", "Waypoints saved for the motor.", m.get("waypoints"), who
        )
        for cause, count in sorted(_dict(m.get("faults")).items()):
            w.counter(
                "motorctl_motor_faults",
                "Faults latched by the motor, by cause.",
                count,
                {**who, "cause": cause},
            )
        timing = _dict(m.get("timing"))
        for key, (name, kind, help_text, scale) in _TIMING.items():
            value = _number(timing.get(key))
            if value is None:
                continue
            scaled = value if scale == 1.0 else value * scale
            unit = "seconds" if name.endswith("_seconds") else None
            w.add(name, kind, help_text, scaled, who, unit=unit)


#: steps.* keys that are times, as gauges in seconds: name, help, scale
_STEP_SECONDS = {
    "max_us": ("motorctl_step_lateness_max_seconds", "The latest step edge since start.", 1e-6),
    "late_threshold_us": (
        "motorctl_step_late_threshold_seconds",
        "A step edge later than this counts as late.",
        1e-6,
    ),
    "min_gap_ns": (
        "motorctl_step_min_gap_seconds",
        "The shortest gap between two step edges of one motor (0: none yet).",
        1e-9,
    ),
}


def _steps(w: _Writer, steps: Mapping[str, Any]) -> None:
    w.summary(
        "motorctl_step_lateness_seconds",
        "How late step edges were, after their planned time (since start).",
        steps,
        steps.get("steps"),
        1e-6,
    )
    for key, (name, help_text, scale) in _STEP_SECONDS.items():
        value = _number(steps.get(key))
        if value is not None:
            w.gauge(name, help_text, value * scale, unit="seconds")
    for key, (name, help_text) in _STEP_COUNTERS.items():
        w.counter(name, help_text, steps.get(key))


def _executor(w: _Writer, executor: Mapping[str, Any]) -> None:
    w.gauge("motorctl_executor_alive", "1 while the step executor runs.", executor.get("alive"))
    kind = executor.get("kind")
    if isinstance(kind, str):
        w.gauge(
            "motorctl_executor_kind", "1 for the kind of step executor running.", 1, {"kind": kind}
        )


def _link(w: _Writer, link: object) -> None:
    if not isinstance(link, Mapping):
        return
    for key, count in sorted(_dict(link.get("counters")).items()):
        if key in _FRAME_ERRORS:
            w.counter(
                "motorctl_link_frame_errors",
                "Frames that failed their checks (answered E1), by reason.",
                count,
                {"reason": _FRAME_ERRORS[key]},
            )
        elif key.startswith("responses_dropped"):  # by cause; the total is their sum
            if key != "responses_dropped":
                w.counter(
                    "motorctl_link_responses_dropped",
                    "Answers never sent, by cause (unsent, wait, held: owed to a host whose "
                    "session ended; shutdown).",
                    count,
                    {"cause": key.removeprefix("responses_dropped_")},
                )
        elif key.startswith("sent_E"):
            w.counter(
                "motorctl_link_error_responses",
                "Error responses sent, by code.",
                count,
                {"code": key.removeprefix("sent_")},
            )
        elif key in _LINK_GAUGES:
            name, help_text = _LINK_GAUGES[key]
            w.gauge(name, help_text, count)
        elif key in _LINK_RENAMED:
            name, help_text, unit = _LINK_RENAMED[key]
            w.counter(name, help_text, count, unit=unit)
        else:
            w.counter(
                f"motorctl_link_{key}",
                f"The link's {key.replace('_', ' ')} (docs/status.md).",
                count,
            )
    w.gauge("motorctl_link_held_frames", "Frames held behind a WaitMoved now.", link.get("held"))
    w.gauge("motorctl_link_waiting", "1 while a WaitMoved holds the answers.", link.get("waiting"))
    peer = link.get("peer")
    if isinstance(peer, str):
        w.gauge("motorctl_link_peer_open", "1 while the host has the port open.", peer == "open")
    w.gauge(
        "motorctl_link_unsent_bytes",
        "Answer bytes not yet taken by the port.",
        link.get("unsent_bytes"),
        unit="bytes",
    )
    processing = _dict(link.get("processing"))
    w.summary(
        "motorctl_link_processing_seconds",
        "From a read to its answers being written (since start).",
        processing,
        processing.get("steps"),
        1e-6,
    )
    max_us = _number(processing.get("max_us"))
    if max_us is not None:
        w.gauge(
            "motorctl_link_processing_max_seconds",
            "The longest processing since start.",
            max_us * 1e-6,
            unit="seconds",
        )


def _state(w: _Writer, state: Mapping[str, Any]) -> None:
    w.gauge(
        "motorctl_state_ok", "1 while the state file is written without errors.", state.get("ok")
    )
    w.counter("motorctl_state_writes", "State file writes.", state.get("writes"))
    w.counter("motorctl_state_write_errors", "State file writes that failed.", state.get("errors"))
    w.counter(
        "motorctl_state_save_errors",
        "SaveHome/SaveWayPoint answered E4 because the state could not be written.",
        state.get("save_errors"),
    )
    w.counter(
        "motorctl_state_motion_refused",
        "Motion commands answered E4 because the motion journal could not be written.",
        state.get("motion_refused"),
    )
    last = _number(state.get("last_write_ms"))
    if last is not None:
        w.gauge(
            "motorctl_state_last_write_seconds",
            "How long the last state write took.",
            last * 1e-3,
            unit="seconds",
        )
    w.counter(
        "motorctl_state_journal_marks",
        "Motions marked in the motion journal.",
        _dict(state.get("journal")).get("marks"),
    )


def _hard_stops(w: _Writer, stops: Mapping[str, Any]) -> None:
    for outcome in ("confirmed", "timed_out", "skipped", "died"):
        w.counter(
            "motorctl_hard_stops",
            "Hard stops' waits for the executor's confirmation, by how they ended.",
            stops.get(outcome),
            {"outcome": outcome},
        )
    for key, q in (("wait_p50_us", "0.5"), ("wait_p99_us", "0.99"), ("wait_max_us", "1")):
        value = _number(stops.get(key))
        if value is not None:
            w.gauge(
                "motorctl_hard_stop_wait_seconds",
                "How long hard stops waited for the "
                "executor's confirmation (quantile 1: the longest).",
                value * 1e-6,
                {"quantile": q},
                unit="seconds",
            )


def _pins_and_dc(w: _Writer, doc: Mapping[str, Any]) -> None:
    for pin in _list(doc.get("pins")):
        if isinstance(pin, Mapping):
            w.gauge(
                "motorctl_pin_level",
                "The IO pin's level (1 high).",
                pin.get("level"),
                {"pin": pin.get("number"), "mode": "output" if pin.get("output") else "input"},
            )
    dc = doc.get("dc")
    if isinstance(dc, Mapping):
        for s in BridgeState:
            w.gauge(
                "motorctl_dc_state",
                "1 for the DC motor bridge's current state.",
                int(dc.get("state") == s.value),
                {"state": s.value},
            )
        w.gauge(
            "motorctl_dc_run_left_seconds",
            "Time left of the DC motor's run (0: not running).",
            dc.get("left_s") if dc.get("running") else 0,
            unit="seconds",
        )


def _drivers(w: _Writer, drivers: object) -> None:
    for d in _list(drivers):
        if not isinstance(d, Mapping):
            continue
        who = {"device": d.get("device"), "chip": d.get("chip")}
        w.counter("motorctl_driver_polls", "Status polls of the driver chip.", d.get("polls"), who)
        w.counter(
            "motorctl_driver_spi_errors",
            "SPI errors talking to the driver chip.",
            d.get("spi_errors"),
            who,
        )
        for flag, count in sorted(_dict(d.get("fault_counts")).items()):
            w.counter(
                "motorctl_driver_faults",
                "Driver chip faults seen, by flag.",
                count,
                {**who, "flag": flag},
            )
        for flag, count in sorted(_dict(d.get("warning_counts")).items()):
            w.counter(
                "motorctl_driver_warnings",
                "Driver chip warnings seen, by flag.",
                count,
                {**who, "flag": flag},
            )
