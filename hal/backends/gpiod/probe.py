"""``motorctld --probe`` for the gpiod backend: the chips, the configured lines and who holds
them, then every line opened at its resting level (STEP low, ENABLE off, the bridge
coasting, pins at their initial levels), the end stops and pins read, and all released.
Nothing moves. Problems go into the report (hal/contract.py), none is raised.

Runs on the probing thread; blocks on GPIO ioctls.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from motorctl.hal.backends.gpiod.boards import describe_chip, layout
from motorctl.hal.backends.gpiod.chip import chip_list, load_api
from motorctl.hal.backends.gpiod.config import wiring_of
from motorctl.hal.contract import ProbeReport, ProblemKind
from motorctl.hal.interfaces import Clock, HalError
from motorctl.hal.spec import HardwareSpec

if TYPE_CHECKING:
    from motorctl.hal.backends.gpiod.backend import GpiodBackend
    from motorctl.hal.backends.gpiod.chip import ChipInfo, GpioApi
    from motorctl.hal.backends.gpiod.wiring import ResolvedLine


def probe_gpio(
    backend: GpiodBackend, spec: HardwareSpec, clock: Clock, report: ProbeReport
) -> None:
    """What ``motorctld --probe`` shows for the GPIO side; opens lines, moves nothing.

    Outputs are requested at their resting levels: STEP low, ENABLE off, the bridge
    coasting, pins at their initial levels.
    """
    wiring = wiring_of(spec)
    api = load_api(wiring.api)
    chips = api.chips()
    report.add(f"libgpiod Python API {api.name} ({api.version})", _chip_rows(api, chips))
    report.add("board layout", [layout(chips)])
    dup = wiring.duplicates()
    if dup:
        for text in dup:
            report.problem(text, ProblemKind.CONFIG)
        return
    try:
        lines = api.resolve(wiring.lines())
    except HalError as exc:
        report.problem(str(exc))
        return
    rows = [_line_row(api, ln) for ln in lines]
    report.add("configured lines (before opening)", rows or ["none"])
    used = {ln.chip_path for ln in lines}
    report.add(
        "chips the config uses",
        [describe_chip(c) for c in chips if c.path in used] or ["none"],
    )
    try:
        api.check_free(lines)
        hw = backend.build(spec, clock, for_probe=True)
    except HalError as exc:
        report.problem(str(exc))
        return
    try:
        io = backend.build_step_io(spec, clock, hw, enable=False)
        io.set_compiled(backend.compiled_lines(io))
    except HalError as exc:
        hw.close()
        report.problem(str(exc))
        return
    report.compiled_lines = io.compiled_text()
    try:
        ends = []
        for i, pair in zip(spec.stepped(), io.endstops, strict=True):
            for which, line in zip(("min", "max"), pair, strict=True):
                if line is not None:
                    active = io.inputs.level(line)
                    level = active != spec.axes[i].endstop_active_low
                    ends.append(
                        f"motors[{i}] {which}: level {int(level)} "
                        f"({'TRIGGERED' if active else 'clear'})"
                    )
        report.add("end stops", ends or ["none wired"])
        pins = [
            f"pin {n}: {'output' if p.is_output else 'input'} level {int(p.read())}"
            for n, p in sorted(hw.pins.items())
        ]
        report.add("pins", pins or ["none"])
        report.add(
            "opened",
            [
                f"all {len(lines)} lines requested as {wiring.consumer!r} "
                "and released; nothing moved"
            ],
        )
    finally:
        io.close()
        hw.close()


def _chip_rows(api: GpioApi, chips: list[ChipInfo]) -> list[str]:
    """Each chip by number, label and line count, with its device and the links to it in /dev
    (Raspberry Pi OS's gpiochip4 -> gpiochip0); the kernel's lack of chips, said, when none."""
    links = {path: name for name, path in api.aliases().items()}
    return [
        f"{describe_chip(c)} ({c.path}"
        + (f"; /dev/{links[c.path]} links to it" if c.path in links else "")
        + ")"
        for c in chips
    ] or [chip_list(chips)]


def _line_row(api: GpioApi, ln: ResolvedLine) -> str:
    """One configured line: its use, how the config names it, where it is and who holds it."""
    info = api.line_info(ln.chip_path, ln.offset)
    held = (f"held by {info.consumer!r}" if info.consumer else "held") if info.used else "free"
    name = f" {info.name!r}" if info.name else ""
    mode = "output" if info.output else "input"
    return (
        f"{ln.use:<22} {ln.ref!s:<16} -> {os.path.basename(ln.chip_path)}:"
        f"{ln.offset}{name} [{ln.chip_label}] ({mode}, {held})"
    )
