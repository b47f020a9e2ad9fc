"""The parts of the live monitor's view, each built from the status document
(docs/status.md) as styled text (:class:`~motorctl.daemon.status.monitor_layout.Para`) or a
table (:class:`~motorctl.daemon.status.monitor_layout.Grid`): the header, the motors, their
step timing, the step edges, the pins and the DC motor, the link, the trace, the last
frames, the drivers. :func:`~motorctl.daemon.status.monitor_view.render` puts them
together. Every field is read defensively (summary.py's ``as_map``, ``as_list``, ``num``): an
older or newer daemon, or one without per-motor timing figures, draws what it has.

Pure functions of a document: no state, no thread of their own (the monitor's drawing
thread calls them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from motorctl.daemon.status import summary
from motorctl.daemon.status.monitor_layout import Grid, Para
from motorctl.daemon.status.summary import as_list, as_map, duration

RECENT_SHOWN = 8


def num(value: object, fmt: str = "{:,}", none: str = "-") -> str:
    """:func:`~motorctl.daemon.status.summary.num` with the monitor's mark for no number."""
    return summary.num(value, fmt, none)


def header_para(doc: Mapping[str, Any], stale: bool = False) -> Para:
    ex = as_map(doc.get("executor"))
    text = Para("motorctld", style="bold")
    if stale:
        text.append(" (last seen)", style="bold red")
    text.append(f"  up {duration(doc.get('uptime_s'))}" + (" then" if stale else ""))
    alive = ex.get("alive")
    text.append("  executor ")
    text.append(f"{ex.get('kind', '?')}", style="bold")
    if ex.get("core"):  # the step core (a daemon before issue 24 does not say)
        text.append(f", {ex.get('core')} core")
    if ex.get("pid"):
        text.append(f" (pid {ex.get('pid')})")
    if alive is False:
        text.append(f" DEAD: {ex.get('reason')}", style="bold red")
    elif alive and stale:
        text.append(" state unknown")
    elif alive:
        text.append(" alive", style="green")
    state = as_map(doc.get("state"))
    if state:
        if state.get("ok", True):
            text.append(f"  state file ok ({num(state.get('writes'))} writes)")
        else:
            text.append(f"  STATE NOT SAVED: {state.get('last_error')}", style="bold red")
    return text


def motors_grid(doc: Mapping[str, Any]) -> Grid:
    table = Grid("motors")
    for name, justify in (
        ("#", "right"),
        ("name", "left"),
        ("state", "left"),
        ("position", "right"),
        ("speed step/s", "right"),
        ("queued", "right"),
        ("waypoints", "right"),
        ("fault", "left"),
    ):
        table.add_column(name, justify=justify)
    for m in as_list(doc.get("motors")):
        m = as_map(m)
        state = str(m.get("state", "?"))
        style = {"idle": "", "fault": "bold red"}.get(state, "bold green")
        fault = m.get("fault")
        fault_text = Para(str(fault), style="red") if fault else Para("")
        if m.get("position_lost"):
            fault_text.append(
                " (position lost: home it)" if fault else "position lost: home it", style="yellow"
            )
        table.add_row(
            str(m.get("index", "?")),
            str(m.get("name", "")),
            Para(state, style=style),
            num(m.get("position")),
            num(m.get("speed"), "{:,.0f}"),
            num(m.get("queued")),
            num(m.get("waypoints")),
            fault_text,
        )
    return table


def timing_grid(doc: Mapping[str, Any]) -> Grid | None:
    """Per-motor step timing and faults by cause (issue 15), when the daemon reports them."""
    motors = [as_map(m) for m in as_list(doc.get("motors"))]
    if not any("timing" in m or "faults" in m for m in motors):
        return None
    table = Grid("step timing per motor")
    for name in (
        "#",
        "late absorbed",
        "slid ms",
        "worst late us",
        "worst lag fs",
        "lag limit fs",
        "microsteps",
        "lag faults",
        "faults by cause",
    ):
        table.add_column(name, justify="left" if name == "faults by cause" else "right")
    for m in motors:
        t = as_map(m.get("timing"))
        faults = (
            ", ".join(
                f"{cause} {count}" for cause, count in sorted(as_map(m.get("faults")).items())
            )
            or "none"
        )
        table.add_row(
            str(m.get("index", "?")),
            num(t.get("late_absorbed")),
            num(t.get("slid_ms"), "{:,.1f}"),
            num(t.get("worst_late_us"), "{:,.0f}"),
            num(t.get("worst_lag_full_steps"), "{:,.2f}"),
            num(t.get("max_lag_full_steps"), "{:,.2f}"),
            num(t.get("microsteps")),
            num(t.get("lag_faults")),
            faults,
        )
    return table


def steps_para(doc: Mapping[str, Any]) -> Para:
    s = as_map(doc.get("steps"))
    text = Para("step edges ", style="bold")
    text.append(num(s.get("steps")))
    text.append(
        f"  lateness p50 {num(s.get('p50_us'), '{:.0f}')}"
        f" p99 {num(s.get('p99_us'), '{:.0f}')}"
        f" p99.9 {num(s.get('p999_us'), '{:.0f}')}"
        f" max {num(s.get('max_us'), '{:.0f}')} us"
    )
    late = s.get("late")
    text.append(f"  late (>{num(s.get('late_threshold_us'), '{:.0f}')} us) ")
    text.append(num(late), style="yellow" if late else "")
    for key, label in (("timing_lost", "timing lost"), ("io_errors", "io errors")):
        value = s.get(key)
        text.append(f"  {label} ")
        text.append(num(value), style="bold red" if value else "")
    # planned segments a re-plan or stop replaced before they ran: normal, no alarm
    text.append(f"  segments discarded {num(s.get('segments_discarded'))}")
    stops = as_map(doc.get("hard_stops"))
    if stops:
        text.append(
            f"\nhard stops confirmed {num(stops.get('confirmed'))}"
            f" timed out {num(stops.get('timed_out'))}"
            f"  wait p99 {num(stops.get('wait_p99_us'), '{:.0f}')} us"
        )
    clamped = as_map(doc.get("clamped"))
    if clamped:
        text.append("  clamped " + ", ".join(f"{k} {v}" for k, v in sorted(clamped.items())))
    return text


def io_para(doc: Mapping[str, Any]) -> Para:
    text = Para("pins ", style="bold")
    pins = [as_map(p) for p in as_list(doc.get("pins"))]
    if not pins:
        text.append("none configured" if "pins" in doc else "not reported")
    for i, p in enumerate(pins):
        if i:
            text.append("  ")
        level = p.get("level")
        word = "?" if level is None else ("H" if level else "L")
        text.append(f"{p.get('number')}:{'out' if p.get('output') else 'in'} ")
        text.append(word, style="bold green" if level else "")
    text.append("\nDC motor ", style="bold")
    dc = doc.get("dc")
    if isinstance(dc, Mapping):
        text.append(str(dc.get("state", "?")), style="bold green" if dc.get("running") else "")
        if dc.get("running"):
            text.append(f", {num(dc.get('left_s'), '{:.1f}')} s left")
    else:
        text.append("none configured" if "dc" in doc else "not reported")
    return text


def link_para(doc: Mapping[str, Any], rate: float | None) -> Para:
    link = as_map(doc.get("link"))
    text = Para("link ", style="bold")
    if not link:
        text.append("not serving")
        return text
    c = as_map(link.get("counters"))
    text.append(f"host port {link.get('peer', '?')}  frames {num(c.get('frames'))}")
    if rate is not None:  # none from a single document (--once) or a stale view
        text.append(f" ({rate:,.1f}/s)")
    bad = {
        k.removesuffix("_errors"): v
        for k, v in c.items()
        if k.endswith("_errors") and k not in ("link_errors", "internal_errors") and v
    }
    text.append("  bad frames ")
    text.append(
        ", ".join(f"{k} {v}" for k, v in sorted(bad.items())) or "0", style="yellow" if bad else ""
    )
    sent = {k.removeprefix("sent_"): v for k, v in c.items() if k.startswith("sent_") and v}
    text.append("  errors sent ")
    text.append(
        ", ".join(f"{k}x{v}" for k, v in sorted(sent.items())) or "none",
        style="yellow" if sent else "",
    )
    text.append(
        f"\n     held {num(link.get('held'))} (max {num(c.get('held_max'))})"
        f"  waiting {'yes' if link.get('waiting') else 'no'}"
        f"  gap discards {num(c.get('gap_discards'))}"
    )
    p = as_map(link.get("processing"))
    text.append(
        f"  processing p50 {num(p.get('p50_us'), '{:.0f}')}"
        f" p99 {num(p.get('p99_us'), '{:.0f}')} max {num(p.get('max_us'), '{:.0f}')} us"
    )
    for key in ("link_errors", "internal_errors", "responses_dropped"):
        if c.get(key):
            text.append(f"  {key.replace('_', ' ')} {c[key]}", style="bold red")
    return text


def trace_para(doc: Mapping[str, Any]) -> Para | None:
    """The link's trace (motorctld --trace), when it records one."""
    t = as_map(doc.get("trace"))
    if not t:
        return None
    text = Para("trace ", style="bold")
    text.append(f"{t.get('file', '?')}")
    if t.get("part"):
        text.append(f" (part {t.get('part')} of session {t.get('session', '?')})")
    text.append(f"  runs {num(t.get('runs'))}  written {num(t.get('bytes_written'))} bytes")
    for key, label in (
        ("dropped_runs", "runs left out"),
        ("write_errors", "write errors"),
        ("lost_bytes", "bytes lost"),
    ):
        value = t.get(key)
        text.append(f"  {label} ")
        text.append(num(value), style="bold red" if value else "")
    return text


def recent_grid(doc: Mapping[str, Any], since_s: float) -> Grid:
    table = Grid("last frames")
    table.add_column("age s", justify="right", no_wrap=True)
    table.add_column("frame", no_wrap=True)
    table.add_column("command")
    table.add_column("answer", no_wrap=True)
    now = doc.get("monotonic_s")
    recent = [as_map(r) for r in as_list(as_map(doc.get("link")).get("recent"))]
    for r in reversed(recent[-RECENT_SHOWN:]):
        at = r.get("at_s")
        age = (
            (now - at + since_s)
            if isinstance(now, int | float) and isinstance(at, int | float)
            else None
        )
        result = r.get("result")
        style = "red" if isinstance(result, str) and result.startswith("E") else ""
        table.add_row(
            num(age, "{:.1f}", "?"),
            str(r.get("frame", "")),
            str(r.get("command", "")),
            Para("(owed)" if result is None else str(result), style=style),
        )
    return table


def drivers_para(doc: Mapping[str, Any]) -> Para | None:
    drivers = [as_map(d) for d in as_list(doc.get("drivers"))]
    if not drivers:
        return None
    text = Para("drivers", style="bold")
    for d in drivers:
        text.append(
            f"\n  {d.get('chip')} {d.get('device')}: polls {num(d.get('polls'))}"
            f"  spi errors {num(d.get('spi_errors'))}  "
            + (f"DRV_STATUS {d.get('drv_status')}" if "drv_status" in d else "")
            + (f"#{d.get('chain_position')} STATUS {d.get('status')}" if "status" in d else "")
        )
        faults = as_map(d.get("fault_counts"))
        if faults:
            text.append(
                "  faults " + ", ".join(f"{k} {v}" for k, v in sorted(faults.items())), style="red"
            )
    return text
