"""The status document as metrics (``motorctld --status --format prometheus|openmetrics``;
docs/status.md, "Metrics"), written by prometheus_client.

Two formats of the same metrics: ``prometheus`` (the Prometheus text format 0.0.4), which
node_exporter's textfile collector reads (a counter's TYPE line names its ``_total``
sample there, so it arrives typed), and ``openmetrics`` for scrapers that ask for
OpenMetrics. prometheus_client is an optional dependency (the ``metrics`` extra; Debian:
python3-prometheus-client), imported by this module only: the daemon never imports it, and
``motorctld --status`` says what to install when it is missing
(``motorctl.daemon.start.main.METRICS_MISSING``).

Pure: a status document in, text out; no socket, no clock. Every name starts with
``motorctl_``, values are in base units (seconds, bytes; steps are the machine's own unit),
counters are counted in ``_total``, summaries have ``_count`` and ``_sum``; what would be a
stateset is a gauge with a ``state`` label, 1 for the current state. The metrics read from
fixed places of the document are tables (:data:`SCALARS`, :data:`MOTOR_FIELDS`,
:data:`LINK_COUNTERS`, :data:`SUMMARIES`, in daemon/status/metric_tables.py): a new status
field is one line there. Fields are read defensively: a field the document lacks (an older
or newer daemon) is left out, never an error.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from prometheus_client import CollectorRegistry
from prometheus_client.exposition import generate_latest as _prometheus_text
from prometheus_client.metrics_core import Metric
from prometheus_client.openmetrics.exposition import generate_latest as _openmetrics_text

from motorctl.daemon.status.metric_tables import (
    LINK_COUNTERS,
    MOTOR_FIELDS,
    SCALARS,
    SUMMARIES,
    Field,
    Summary,
)
from motorctl.hal.interfaces import BridgeState
from motorctl.motion.types import MotorState

FORMATS = ("prometheus", "openmetrics")

Labels = Mapping[str, object]


def _unit(name: str) -> str:
    for unit in ("seconds", "bytes"):
        if name.endswith("_" + unit):
            return unit
    return ""


#: the document's single values


class _Families:
    """prometheus_client's families, in the order first named; each family's samples
    together. One name, one type: a second type for a name is a programming error."""

    def __init__(self) -> None:
        self.families: dict[str, Metric] = {}

    def family(self, name: str, kind: str, help_text: str) -> Metric:
        family = self.families.get(name)
        if family is None:
            family = self.families[name] = Metric(name, help_text, kind, _unit(name))
        elif family.type != kind:
            raise ValueError(f"{name} is a {family.type}, not a {kind}")
        return family

    def add(
        self,
        name: str,
        kind: str,
        help_text: str,
        value: object,
        labels: Labels | None = None,
        suffix: str = "",
        scale: float = 1.0,
    ) -> None:
        number = _number(value)
        if number is None:
            return
        family = self.family(name, kind, help_text)
        suffix = suffix or ("_total" if kind == "counter" else "")
        text = {k: str(v) for k, v in (labels or {}).items() if v is not None}
        if scale != 1.0:  # 12 digits: no 9.999999999999999e-05 for 100 us
            number = float(f"{number * scale:.12g}")
        family.add_sample(name + suffix, text, number)

    def gauge(self, name: str, help_text: str, value: object, labels: Labels | None = None) -> None:
        self.add(name, "gauge", help_text, value, labels)

    def counter(
        self, name: str, help_text: str, value: object, labels: Labels | None = None
    ) -> None:
        self.add(name, "counter", help_text, value, labels)

    def field(self, f: Field, source: Mapping[str, Any], labels: Labels | None = None) -> None:
        self.add(f.name, f.kind, f.help, _get(source, f.key), labels, scale=f.scale)

    def summary(self, s: Summary, figures: Mapping[str, Any]) -> None:
        """Its quantiles (when present), ``_count`` and ``_sum``: all, or none of it."""
        count, total = _number(figures.get(s.count)), _number(figures.get(s.sum))
        if count is None or total is None:
            return
        for key, q in s.quantiles:
            self.add(s.name, "summary", s.help, figures.get(key), {"quantile": q}, scale=s.scale)
        self.add(s.name, "summary", s.help, count, suffix="_count")
        self.add(s.name, "summary", s.help, total, suffix="_sum", scale=s.scale)

    def info(self, name: str, help_text: str, labels: Mapping[str, str]) -> None:
        family = self.family(name, "info", help_text)
        family.add_sample(name + "_info", dict(labels), 1)


def _number(value: object) -> float | int | None:
    """A sample's value: bools as 0/1, numbers as they are; None (absent, text, NaN)."""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return value
    if isinstance(value, float) and not math.isnan(value):
        return value
    return None


def _get(source: Mapping[str, Any], key: str) -> object:
    value: object = source
    for part in key.split("."):
        if not isinstance(value, Mapping):
            return None
        value = value.get(part)
    return value


def _dict(value: object) -> Mapping[str, Any]:
    return value if isinstance(value, Mapping) else {}


def _list(value: object) -> Iterable[Any]:
    return value if isinstance(value, list) else []


class _Collector:
    """What prometheus_client's registry collects: the families, once."""

    def __init__(self, families: _Families) -> None:
        self._families = families

    def collect(self) -> Iterator[Metric]:
        yield from self._families.families.values()


def render(families: _Families, fmt: str) -> str:
    """The families in ``fmt`` (:data:`FORMATS`)."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Collector(families))
    write = _openmetrics_text if fmt == "openmetrics" else _prometheus_text
    return write(registry).decode("utf-8")


def metrics(doc: Mapping[str, Any], fmt: str = "prometheus") -> str:
    """The status document ``doc`` (``motorctld --status``) as metrics in ``fmt``."""
    w = _Families()
    w.gauge("motorctl_up", "1: the status was read from a running motorctld.", 1)
    version = doc.get("version")
    if isinstance(version, str):
        w.info("motorctl_build", "The running motorctld's version.", {"version": version})
    unix, uptime = _number(doc.get("unix_s")), _number(doc.get("uptime_s"))
    if unix is not None and uptime is not None:
        w.gauge(
            "motorctl_start_time_seconds",
            "When motorctld started (Unix time).",
            round(unix - uptime, 3),
        )
    for f in SCALARS:
        w.field(f, doc)
    for s in SUMMARIES:
        w.summary(s, _dict(_get(doc, s.key)))
    w.gauge("motorctl_trace_enabled", "1 while motorctld traces its link.", "trace" in doc)
    _motors(w, doc)
    _executor(w, _dict(doc.get("executor")))
    _link(w, doc.get("link"))
    for outcome in ("confirmed", "timed_out", "skipped", "died"):
        w.counter(
            "motorctl_hard_stops",
            "Hard stops' waits for the executor's confirmation, by how they ended.",
            _dict(doc.get("hard_stops")).get(outcome),
            {"outcome": outcome},
        )
    for what, count in sorted(_dict(doc.get("clamped")).items()):
        w.counter(
            "motorctl_clamped_values",
            "Command values clamped to the motor's limits.",
            count,
            {"value": what},
        )
    _pins_and_dc(w, doc)
    _drivers(w, doc.get("drivers"))
    return render(w, fmt)


def down(fmt: str = "prometheus") -> str:
    """The metrics when the daemon could not be read: ``motorctl_up 0``."""
    w = _Families()
    w.gauge("motorctl_up", "1: the status was read from a running motorctld.", 0)
    return render(w, fmt)


def _motors(w: _Families, doc: Mapping[str, Any]) -> None:
    states = [s.value for s in MotorState]
    for m in _list(doc.get("motors")):
        if not isinstance(m, Mapping):
            continue
        who = {"motor": m.get("index"), "name": m.get("name")}
        for f in MOTOR_FIELDS:
            w.field(f, m, who)
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
        for cause, count in sorted(_dict(m.get("faults")).items()):
            w.counter(
                "motorctl_motor_faults",
                "Faults latched by the motor, by cause.",
                count,
                {**who, "cause": cause},
            )


def _executor(w: _Families, executor: Mapping[str, Any]) -> None:
    kind = executor.get("kind")
    if isinstance(kind, str):
        w.gauge(
            "motorctl_executor_kind", "1 for the kind of step executor running.", 1, {"kind": kind}
        )


def _link(w: _Families, link: object) -> None:
    if not isinstance(link, Mapping):
        return
    for key, count in sorted(_dict(link.get("counters")).items()):
        if key == "responses_dropped":  # the sum of responses_dropped_<cause>, not repeated
            continue
        if key in LINK_COUNTERS:
            name, kind, help_text, labels = LINK_COUNTERS[key]
            w.add(name, kind, help_text, count, labels)
        else:  # a counter without a name of its own: motorctl_link_<key>_total
            w.counter(
                f"motorctl_link_{key.removeprefix('link_')}",
                f"The link's {key.replace('_', ' ')} (docs/status.md).",
                count,
            )
    peer = link.get("peer")
    if isinstance(peer, str):
        w.gauge("motorctl_link_peer_open", "1 while the host has the port open.", peer == "open")


def _pins_and_dc(w: _Families, doc: Mapping[str, Any]) -> None:
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
        )


def _drivers(w: _Families, drivers: object) -> None:
    for d in _list(drivers):
        if not isinstance(d, Mapping):
            continue
        who = {"device": d.get("device"), "chip": d.get("chip")}
        if "chain_position" in d:  # a daisy chain's chips share the device
            who["chain_position"] = d.get("chain_position")
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
