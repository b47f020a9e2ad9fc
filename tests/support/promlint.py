"""The lint of ``promtool check metrics`` in Python, on prometheus_client's parser of the
Prometheus text format (the format node_exporter's textfile collector reads).

``make test`` lints the metrics with it: it never installs Debian's ``prometheus`` package (a
whole server) to get promtool. promtool itself runs where it is installed already
(tests/daemon/status/test_metrics.py) and in ``make test-deb`` on the installed package's
timer output (tests/deb/check-install.sh). The rules are promtool's (client_golang's
promlint): help text, ``_total`` on counters and only there, names and label names in
snake_case without ``:``, no metric type in a name, base units, no abbreviated units, the
suffixes and labels of histograms and summaries nowhere else. Stricter than promtool in what
a scrape rejects but promtool lets pass: a family given twice (a second HELP or TYPE line,
or its samples not together) and a series given twice. A line the parser cannot read is a
problem too, never an exception.

Owner: the calling test (pure functions).
"""

from __future__ import annotations

import re
from collections import Counter

from prometheus_client.metrics_core import Metric
from prometheus_client.parser import text_string_to_metric_families

BASE_UNITS = {"amperes", "bytes", "celsius", "grams", "joules", "kelvin", "meters", "metres"}
BASE_UNITS |= {"seconds", "volts"}
# a unit that is not a base unit, and the base unit to use instead
OTHER_UNITS = {"minutes": "seconds", "hours": "seconds", "days": "seconds", "weeks": "seconds"}
OTHER_UNITS |= {"kelvins": "kelvin", "fahrenheit": "celsius", "rankine": "celsius"}
OTHER_UNITS |= {"inches": "meters", "yards": "meters", "miles": "meters", "bits": "bytes"}
OTHER_UNITS |= {"calories": "joules", "pounds": "grams", "ounces": "grams"}
PREFIXES: tuple[str, ...] = ("pico", "nano", "micro", "milli", "centi", "deci", "deca", "hecto")
PREFIXES += ("kilo", "kibi", "mega", "mibi", "giga", "gibi", "tera", "tebi", "peta", "pebi")
ABBREVIATIONS = {"s", "ms", "us", "ns", "sec", "b", "kb", "mb", "gb", "tb", "pb", "m", "h", "d"}
TYPES = ("counter", "gauge", "summary", "histogram")
CAMEL = re.compile(r"[a-z][A-Z]")


def lint(text: str) -> list[str]:
    """Every problem promtool's lint (and a scrape) would find in ``text``, one line each
    (``NAME what``); empty when there is none."""
    try:
        families: list[Metric] = list(text_string_to_metric_families(text))
    except ValueError as exc:
        return [f"text format parsing error: {exc}"]
    problems = [f"{name} {what}" for name, what in _repeated(text, families)]
    # the names as the TYPE lines give them: the parser takes a counter's _total off its
    # family's name and puts it on its samples whether the text had it or not
    typed = {line.split()[2] for line in text.splitlines() if _meta(line, "TYPE")}
    for family in families:
        exposed = family.name
        if family.type == "counter" and family.name not in typed:
            exposed += "_total"
        problems += [f"{exposed} {what}" for what in _family(family, exposed)]
    return problems


def _repeated(text: str, families: list[Metric]) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for kind in ("HELP", "TYPE"):
        lines = Counter(line.split()[2] for line in text.splitlines() if _meta(line, kind))
        out += [(name, f"has {n} {kind} lines") for name, n in lines.items() if n > 1]
    named = Counter(f.name for f in families)
    out += [(name, "is given in more than one place") for name, n in named.items() if n > 1]
    series = Counter((s.name, tuple(sorted(s.labels.items()))) for f in families for s in f.samples)
    out += [(f"{n}{dict(labels)}", "is given twice") for (n, labels), c in series.items() if c > 1]
    return out


def _meta(line: str, kind: str) -> bool:
    parts = line.split()
    return len(parts) >= 3 and parts[0] == "#" and parts[1] == kind


def _family(family: Metric, exposed: str) -> list[str]:
    """promlint's rules on one family, named ``exposed`` in the text."""
    kind = family.type
    problems = [] if family.documentation else ["no help text"]
    if kind == "counter" and not exposed.endswith("_total"):
        problems.append('counter metrics should have "_total" suffix')
    if kind != "counter" and family.name.endswith("_total"):
        problems.append('non-counter metrics should not have "_total" suffix')
    if kind != "histogram" and family.name.endswith("_bucket"):
        problems.append('non-histogram metrics should not have "_bucket" suffix')
    for suffix in ("_count", "_sum"):
        if kind not in ("histogram", "summary") and family.name.endswith(suffix):
            problems.append(f'non-histogram and non-summary metrics should not have "{suffix}"')
    labels = {label for s in family.samples for label in s.labels}
    if kind != "histogram" and "le" in labels:
        problems.append('non-histogram metrics should not have "le" label')
    if kind != "summary" and "quantile" in labels:
        problems.append('non-summary metrics should not have "quantile" label')
    types = [t for t in TYPES if f"_{t}_" in exposed or exposed.endswith(f"_{t}")]
    problems += [f"metric name should not include type '{t}'" for t in types]
    if ":" in exposed:
        problems.append("metric names should not contain ':'")
    if CAMEL.search(exposed):
        problems.append("metric names should be written in 'snake_case' not 'camelCase'")
    if any(CAMEL.search(label) for label in labels):
        problems.append("label names should be written in 'snake_case' not 'camelCase'")
    return problems + _units(exposed)


def _units(name: str) -> list[str]:
    words = name.split("_")
    if any(word in ABBREVIATIONS for word in words):
        return ["metric names should not contain abbreviated units"]
    for word in words:
        for prefix in ("", *PREFIXES):
            unit = word.removeprefix(prefix) if word.startswith(prefix) else None
            if unit in BASE_UNITS or unit in OTHER_UNITS:
                base = unit if unit in BASE_UNITS else OTHER_UNITS[unit]
                return [] if word == base else [f'use base unit "{base}" instead of "{word}"']
    return []
