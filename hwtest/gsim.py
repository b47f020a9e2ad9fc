"""gpio-sim from the outside, inside the test VM (hwtest/vm): the simulated world's side.

``value`` of a sim line is what the line drives (output) or reads (input); writing ``pull``
is what the outside world drives onto an input, and makes edge events. The kernel's
``gpio:gpio_value`` trace events count and order every level a program sets. Adapted from
the verified recipe (shared notes, gpio-sim/tests/gsim.py). Used by one test process at a
time (the tracing buffer is global); blocks only on sysfs/tracefs file I/O.
"""

from __future__ import annotations

import glob
import re
from dataclasses import dataclass

TRACE = "/sys/kernel/tracing"
SIM = "/sys/devices/platform/gpio-sim.0"

#: the banks the tier's VMs have (hwtest/run): gpiochip0 = 32 lines named GPIO0..GPIO31 (as
#: a Raspberry Pi's), gpiochip1 = 16 lines named B1_0..B1_15
BANKS = "32 16"
NAMES = "GPIO B1_"


def available() -> bool:
    return bool(glob.glob(f"{SIM}/gpiochip*"))


def sim_dir(chip: str) -> str:
    """gpio-sim's sysfs folder of a live chip, whichever gpio-sim device made it (the tier's
    own banks are gpio-sim.0's; hwtest/boards.py makes one device per chip)."""
    found = glob.glob(f"/sys/devices/platform/gpio-sim.*/{chip}")
    if len(found) != 1:
        raise LookupError(f"gpio-sim chip {chip}: {found or 'not found'}")
    return found[0]


def sim_value(offset: int, chip: str = "gpiochip0") -> bool:
    with open(f"{sim_dir(chip)}/sim_gpio{offset}/value") as f:
        return f.read().strip() == "1"


def sim_pull(offset: int, high: bool, chip: str = "gpiochip0") -> None:
    with open(f"{sim_dir(chip)}/sim_gpio{offset}/pull", "w") as f:
        f.write("pull-up" if high else "pull-down")


def chip_base(chip: str = "gpiochip0") -> int:
    """The global GPIO number of offset 0 (what the trace prints), from debugfs."""
    with open("/sys/kernel/debug/gpio") as f:
        for line in f:
            m = re.match(r"(gpiochip\d+): GPIOs (\d+)-(\d+)", line)
            if m and m.group(1) == chip:
                return int(m.group(2))
    raise LookupError(chip)


def _w(name: str, value: object) -> None:
    with open(f"{TRACE}/{name}", "w") as f:
        f.write(str(value))


def trace_start(buffer_kb: int = 8192) -> None:
    """Clear the ring buffer and record gpio_value and gpio_direction, on CLOCK_MONOTONIC."""
    _w("tracing_on", 0)
    _w("buffer_size_kb", buffer_kb)
    _w("trace_clock", "mono")
    for ev in ("gpio_value", "gpio_direction"):
        _w(f"events/gpio/{ev}/enable", 1)
    _w("trace", "")
    _w("tracing_on", 1)


def trace_stop() -> None:
    _w("tracing_on", 0)


@dataclass(frozen=True)
class Ev:
    ts: float
    event: str  # gpio_value | gpio_direction
    gpio: int
    op: str  # get | set | in | out
    value: int


_RE = re.compile(
    r"^\s*(.*?)-\d+\s+\[\d+\].*?(\d+\.\d+): (gpio_value|gpio_direction): (\d+)\s+"
    r"(get|set|in|out) \(?(-?\d+)\)?"
)


def trace_read() -> list[Ev]:
    out = []
    with open(f"{TRACE}/trace") as f:
        for line in f:
            m = _RE.match(line)
            if m:
                out.append(
                    Ev(float(m.group(2)), m.group(3), int(m.group(4)), m.group(5), int(m.group(6)))
                )
    return out


def trace_lost() -> int:
    n = 0
    for st in glob.glob(f"{TRACE}/per_cpu/cpu*/stats"):
        with open(st) as f:
            for line in f:
                k, _, v = line.partition(":")
                if k.strip() in ("overrun", "dropped events"):
                    n += int(v)
    return n


def sets(events: list[Ev], gpio: int) -> list[Ev]:
    """The levels a program set on one line (not the kernel's reads), in order."""
    return [e for e in events if e.event == "gpio_value" and e.op == "set" and e.gpio == gpio]


def changes(events: list[Ev]) -> list[Ev]:
    """Only the sets that change the level (libgpiod v1 rewrites every line of a multi-line
    handle on each write, so a line's own level repeats in the trace)."""
    out: list[Ev] = []
    for e in events:
        if not out or e.value != out[-1].value:
            out.append(e)
    return out
