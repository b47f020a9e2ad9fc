"""The status document as a person reads it: what ``motorctld --status`` prints on a
terminal (docs/status.md, "On a terminal"), one screen instead of the whole document.

:func:`summary` is pure: a document in, lines of text out. It shows the daemon and its
step executor, the real time the executor got (each refusal with its reason and fix), each
motor (state, position, speed, its fault and last error), the link, the step timing, the
state file, pins, DC motor and trace. Every field is read defensively: an older or newer
daemon shows what it has, and a motor's last error (the dispatcher's, when the daemon
reports one) is read from whatever error field the motor carries.

Threads: the caller's; nothing here keeps state.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

#: the real-time requests in the order shown, with their names in words
REALTIME_ITEMS = (
    ("sched_fifo", "SCHED_FIFO"),
    ("memory_lock", "mlockall"),
    ("cpu_affinity", "CPU pinning"),
)


def as_map(value: object) -> Mapping[str, Any]:
    """A document's field read as a table: ``{}`` when it is anything else (an older or
    newer daemon's document; the live monitor reads so too)."""
    return value if isinstance(value, Mapping) else {}


def as_list(value: object) -> Sequence[Any]:
    """A document's field read as a list: ``[]`` when it is anything else."""
    return value if isinstance(value, list) else []


def num(value: object, fmt: str = "{:,}", none: str = "?") -> str:
    """A number as ``fmt`` says; ``none`` for anything else (a bool is not a number)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return none
    return fmt.format(value)


def duration(seconds: object) -> str:
    """``seconds`` as H:MM:SS (the monitor shows uptime and ages so too); ``?`` for no number."""
    if not isinstance(seconds, int | float):
        return "?"
    s = int(seconds)
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}"


def summary(doc: Mapping[str, Any], width: int = 100) -> str:
    """``doc`` in a screen of text, lines at most ``width`` long where words allow."""
    lines = [*_head(doc), *_realtime(doc, width), *_motors(doc, width)]
    for line in [*_link(doc), *_steps(doc), *_rest(doc)]:
        lines += _wrap(line.lstrip(), width, line[: len(line) - len(line.lstrip())])
    return "\n".join(lines) + "\n"


def _head(doc: Mapping[str, Any]) -> list[str]:
    ex = as_map(doc.get("executor"))
    kind = ex.get("kind", "?")
    if kind == "none":
        executor = "no step executor (every motor runs its driver's own ramp)"
    else:
        pid = f" (pid {ex['pid']})" if isinstance(ex.get("pid"), int) else ""
        alive = "alive" if ex.get("alive") else f"DEAD: {ex.get('reason') or 'not running'}"
        executor = f"step executor {kind}{pid}, step core {ex.get('core') or '?'}, {alive}"
    return [f"motorctld {doc.get('version', '?')}, up {duration(doc.get('uptime_s'))}: {executor}"]


def _wrap(text: str, width: int, indent: str) -> list[str]:
    """``text`` in lines of at most ``width`` where its words allow, the first indented by
    ``indent``, the rest four more."""
    wrapped = textwrap.wrap(
        text,
        width,
        initial_indent=indent,
        subsequent_indent=indent + "    ",
        break_on_hyphens=False,
        break_long_words=False,
    )
    return wrapped or [indent]


def _realtime(doc: Mapping[str, Any], width: int) -> list[str]:
    ex = as_map(doc.get("executor"))
    rt = as_map(ex.get("realtime"))
    if not rt:
        why = "no step executor" if ex.get("kind") == "none" else "not reported by this daemon"
        return [f"real time: {why}"]
    return realtime_lines(rt, width)


def realtime_lines(
    rt: Mapping[str, Any], width: int, indent: str = "", label: str = "real time: "
) -> list[str]:
    """A real-time report (the status document's ``executor.realtime``) in lines after
    ``label``: what was granted on one, each refusal with its reason and fix on lines of
    its own."""
    refused: list[str] = []
    rest: list[str] = []
    for key, name in REALTIME_ITEMS:
        o = as_map(rt.get(key))
        state, what = o.get("state"), str(o.get("what", name))
        if state == "granted":
            rest.append(f"{what} granted")
        elif state == "refused":
            refused += _wrap(f"{what} REFUSED: {o.get('reason') or o.get('error')}", width, "  ")
            refused += _wrap(f"fix: {o.get('fix') or '?'}", width, "    ")
        else:
            rest.append(f"{name} not asked ({what})")
    kernel = as_map(rt.get("kernel"))
    preempt = "PREEMPT_RT" if kernel.get("preempt_rt") else "not PREEMPT_RT (docs/timing.md)"
    rest.append(f"kernel {kernel.get('release', '?')} {preempt}")
    if refused:
        head = [f"{label}REFUSED, steps best effort", *refused]
        lines = head + _wrap("; ".join(rest), width, "  ")
    else:
        lines = _wrap(label + "; ".join(rest), width, "")
    return [indent + line for line in lines]


#: what a motor's error record may call its parts (the dispatcher's, as the daemon reports it)
_ERROR_PARTS = ("code", "command", "reason", "text", "message")


def _last_error(m: Mapping[str, Any]) -> str | None:
    """The motor's last error answer in words, from whichever field carries it: a
    ``last...error...`` field as it is; another ``...error...`` field when it reads as one
    (text, or code, command, reason), not counts."""
    keys = sorted((k for k in m if "error" in k), key=lambda k: not k.startswith("last"))
    for key in keys:
        value = m[key]
        if isinstance(value, str) and value:
            return value
        if not isinstance(value, Mapping) or not value:
            continue
        code, command = value.get("code"), value.get("command")
        reason = value.get("reason") or value.get("text") or value.get("message")
        known = [str(code) if code else "", f"on {command}" if command else ""]
        words = " ".join(w for w in [*known, f"({reason})" if reason else ""] if w)
        if words:
            return words
        if key.startswith("last"):
            return ", ".join(
                f"{k} {v}" for k, v in value.items() if isinstance(v, str | int | float)
            )
    return None


def _motors(doc: Mapping[str, Any], width: int) -> list[str]:
    motors = [as_map(m) for m in as_list(doc.get("motors"))]
    if not motors:
        return ["motors: none reported"]
    lines = ["motors:"]
    for m in motors:
        state = str(m.get("state", "?"))
        state = state.upper() if state == "fault" else state
        where = f"position {num(m.get('position'), '{}')}"
        if m.get("position_lost"):
            where += " (lost: home it)"
        line = (
            f"  {m.get('index', '?')} {m.get('name', '?')}: {state}, "
            f"{where}, speed {num(m.get('speed'), '{:.0f}')} step/s"
        )
        if m.get("queued"):
            line += f", {m['queued']} queued"
        lines.append(line)
        if m.get("fault"):
            lines += _wrap(f"fault: {m['fault']}", width, "      ")
        error = _last_error(m)
        if error:
            lines += _wrap(f"last error: {error}", width, "      ")
    return lines


def _link(doc: Mapping[str, Any]) -> list[str]:
    link = as_map(doc.get("link"))
    if not link:
        return ["link: not serving"]
    c = as_map(link.get("counters"))
    bad = sum(v for k, v in c.items() if k.endswith("_errors") and k in _FRAME_ERRORS)
    sent = {k.removeprefix("sent_"): v for k, v in c.items() if k.startswith("sent_") and v}
    errors = ", ".join(f"{k} x{v}" for k, v in sorted(sent.items())) or "none"
    p = as_map(link.get("processing"))
    device = f" {link['device']}" if link.get("device") else ""
    line = (
        f"link: host port{device} {link.get('peer', '?')}; {num(c.get('frames'))} frames, "
        f"{num(bad)} bad; error answers {errors}; answer time p99 "
        f"{num(p.get('p99_us'), '{:,.0f}')} us"
    )
    if p.get("over_target"):
        target = num(p.get("target_us"), "{:,.0f}")
        line += f" ({num(p['over_target'])} reads over the {target} us target)"
    # the last error answer not of a motor (a bad frame, say), when the daemon reports one
    other = _last_error({k: v for k, v in doc.items() if k in ("errors", "last_error")})
    return [line, f"  last error of no motor: {other}"] if other else [line]


#: the link's frame error counters (each a bad frame, answered E1)
_FRAME_ERRORS = ("checksum_errors", "unknown_errors", "padding_errors", "length_errors")


def _steps(doc: Mapping[str, Any]) -> list[str]:
    s = as_map(doc.get("steps"))
    if not s:
        return ["step timing: not reported"]
    us = "{:,.0f}"
    return [
        f"step timing: {num(s.get('steps'))} step edges, late by p50 {num(s.get('p50_us'), us)}"
        f" p99 {num(s.get('p99_us'), us)} max {num(s.get('max_us'), us)} us; "
        f"{num(s.get('late'))} later than {num(s.get('late_threshold_us'), us)} us; "
        f"{num(s.get('timing_lost'))} timing lost",
        f"  planned segments discarded by re-plans and stops: {num(s.get('segments_discarded'))}"
        " (normal; no step lost)",
    ]


def _rest(doc: Mapping[str, Any]) -> list[str]:
    lines = []
    state = as_map(doc.get("state"))
    if state:
        ok = "ok" if state.get("ok") else f"NOT SAVED: {state.get('last_error')}"
        lines.append(f"state file: {ok}, {num(state.get('writes'))} writes")
    pins = [as_map(p) for p in as_list(doc.get("pins"))]
    words = [
        f"{p.get('number')} {'out' if p.get('output') else 'in'} "
        f"{'?' if p.get('level') is None else 'high' if p.get('level') else 'low'}"
        for p in pins
    ]
    dc = as_map(doc.get("dc"))
    motor = f"{dc.get('state', '?')}{', running' if dc.get('running') else ''}" if dc else "none"
    lines.append(f"pins: {', '.join(words) or 'none'}; DC motor: {motor}")
    trace = as_map(doc.get("trace"))
    if trace:
        lines.append(f"trace: {trace.get('file')}, {num(trace.get('runs'))} runs")
    lines.append("everything: motorctld --status --json (docs/status.md)")
    return lines
