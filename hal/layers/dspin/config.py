"""The dSPIN layer's declaration (:class:`DspinDeclaration`, hal/contract.py): its config
section ``[motors.dspin]`` (one motor's chip: which one, where in which chain, how it is
set up), the rules across motors (a chain's positions run 0..N-1 on its node, one clock per
chain) and the driver spec (:class:`~motorctl.hal.dspin.spec.DspinSpec`) a motor's section
gives it.

The layer works with every hardware backend (the chip moves the motor itself: no STEP/DIR
lines), so it is named in `motorctl.hal.registry.LAYERS`, not as a backend. Like every
declaration it imports no hardware library: a config is checked without py-spidev.

Pure declarations and conversions: no state, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from motorctl.hal.contract import ChipTable, LayerDeclaration, MotorEntry
from motorctl.hal.dspin.counter import ABS_POS_SPAN
from motorctl.hal.dspin.spec import SWITCH_SIDES, DspinSpec
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import DEFAULT_DEVICE, DEVICE_PATTERN
from motorctl.schema import (
    Extension,
    Rule,
    Violation,
    boolean,
    choice,
    integer,
    number,
    section,
    text,
)

if TYPE_CHECKING:
    from motorctl.hal.dspin.chips import Chip


def _chips() -> Mapping[str, Chip]:
    from motorctl.hal.dspin.chips import CHIPS as chips

    return chips


#: the chips ``[motors.dspin] driver`` takes, by that name (hal/dspin/chips.py's tables,
#: imported when a motor's chip is asked for: a config without a dSPIN motor imports none)
CHIPS: Final[Mapping[str, Chip]] = ChipTable(
    ("l6470", "l6472", "l6480", "powerstep01", "powerstep01-current"), _chips
)

#: a GPIO line as a backend names it (the gpiod backend parses it, and finds it, at start)
LINE_TEXT = '"" (not wired) or a GPIO line: "chip:offset" (gpiochip0:25) or a line name (GPIO25)'
_LINE = re.compile(r"^$|^(/dev/)?[A-Za-z0-9_.-]+:[0-9]+$|^[A-Za-z_][A-Za-z0-9_.-]*$")


def _line(value: str) -> str | None:
    return None if _LINE.match(value) else "not a GPIO line"


@section(
    "An ST dSPIN driver (L6470, L6472, L6480, powerSTEP01) on SPI that moves the motor "
    "itself (absent: no dSPIN chip).",
    notes="""\
The chip runs its own ramps: the motor has no STEP/DIR lines, positions are the chip's
ABS_POS (22 bits of microsteps: -2097152..2097151; a rotary axis counts on past them as the
chip's counter wraps, and its `steps_per_rev` is at most 4194304), homing is the chip's
GoUntil on its SW input and ReleaseSW back off it, or with `homing.source = "stall"` (a
chip with STALL_TH, `switch = "none"`) a run that the chip's stall detection ends
(docs/dspin.md). Chips on one
chip select form a daisy chain: `position` 0 is the chip whose SDI is wired to the host's
MOSI, the others follow in the order of the wiring; every chip of a chain is configured
(positions 0..N-1) and all of a chain's motors give the same `spi_speed_hz`. At start each
chip's STATUS is read and its latched power-up flags cleared, its CONFIG read and compared
with the model's reset value (another value: the daemon refuses to start, naming the chip
and what it read), then the bridges go to high impedance and STEP_MODE, CONFIG, the KVAL
(voltage mode) or TVAL (current mode) registers, OCD_TH, STALL_TH and ALARM_EN are written
and read back. While running the HAL's driver poller reads every chip's STATUS (GetStatus,
one exchange per chain) every `[drivers] poll_ms`: UVLO, thermal shutdown, overcurrent, a
stall (STEP_LOSS_A/B, except during stall homing) and a command the chip refused fault the
motor (E4); a thermal warning is logged. A chip's FLAG line (`flag`) makes the poller read
its chain at once; its BUSY line (`busy`) spares the reads of a motor at rest.""",
)
@dataclass(frozen=True)
class DspinAxisConfig:
    """[motors.dspin]: one motor's dSPIN chip."""

    driver: str = choice(
        "l6470",
        tuple(CHIPS),
        "The chip (powerstep01: voltage mode, powerstep01-current: current mode); its "
        "CONFIG reset value is checked at start.",
    )
    spi: str = text(
        DEFAULT_DEVICE,
        "The SPI device of the chain: bus B, chip select C.",
        pattern=DEVICE_PATTERN,
        pattern_text="/dev/spidevB.C, for example /dev/spidev0.1",
    )
    position: int = integer(
        0, 0, 15, "Place in the daisy chain: 0 = the chip whose SDI is the host's MOSI."
    )
    spi_speed_hz: int = integer(
        DspinSpec.spi_speed_hz,
        10_000,
        5_000_000,
        "SPI clock; the chips accept up to 5 MHz (SPI mode 3).",
    )
    microsteps: int = integer(
        16,
        1,
        128,
        "Microsteps per full step (STEP_SEL; a power of two, up to 16 in current mode); "
        "one step of the protocol is one microstep.",
    )
    kval_hold: int = integer(41, 0, 255, "Voltage mode: KVAL_HOLD, duty = value/256 at rest.")
    kval_run: int = integer(41, 0, 255, "Voltage mode: KVAL_RUN, at constant speed.")
    kval_acc: int = integer(41, 0, 255, "Voltage mode: KVAL_ACC, while accelerating.")
    kval_dec: int = integer(41, 0, 255, "Voltage mode: KVAL_DEC, while decelerating.")
    tval_hold: int = integer(41, 0, 127, "Current mode: TVAL_HOLD, the current at rest.")
    tval_run: int = integer(41, 0, 127, "Current mode: TVAL_RUN, at constant speed.")
    tval_acc: int = integer(41, 0, 127, "Current mode: TVAL_ACC, while accelerating.")
    tval_dec: int = integer(41, 0, 127, "Current mode: TVAL_DEC, while decelerating.")
    ocd_th: int = integer(
        8, 0, 31, "OCD_TH, the overcurrent threshold register (L6470/L6472: 0..15)."
    )
    stall_th: int = integer(
        16,
        0,
        127,
        "STALL_TH, the stall threshold register (L6480/powerSTEP01: 0..31): STEP_LOSS_A/B, "
        'a fault, or the end of the run with homing.source = "stall".',
    )
    switch: str = choice(
        DspinSpec.switch,
        SWITCH_SIDES,
        "The end stop wired to the chip's SW input: min (below), max (above) or none.",
    )
    hiz_at_exit: bool = boolean(
        DspinSpec.hiz_at_exit, "Bridges to high impedance when motorctld exits."
    )
    # -- the chip's FLAG and BUSY outputs on GPIO lines (docs/dspin.md, "FLAG and BUSY") --
    flag: str = text(
        DspinSpec.flag,
        "The GPIO line the chip's FLAG output is wired to (open drain, low on an alarm): "
        'a falling edge reads STATUS at once; "" not wired (the STATUS poll). Chips of '
        "one chain may name one line (wired-OR).",
        check=_line,
        check_text=LINE_TEXT,
    )
    busy: str = text(
        DspinSpec.busy,
        "The GPIO line the chip's BUSY output is wired to (open drain, low while a "
        'command runs): at rest the motor is watched on it, not over SPI; "" not wired. '
        "Chips of one chain may name one line (wired-OR).",
        check=_line,
        check_text=LINE_TEXT,
    )


def _chip(v: DspinAxisConfig) -> Chip:
    return CHIPS[v.driver]


def registers(v: DspinAxisConfig) -> tuple[tuple[str, int], ...]:
    """The registers written at start beyond STEP_MODE (register name -> value), as the
    chip has them: KVAL_* in voltage mode, TVAL_* in current mode; STALL_TH where the chip
    detects stalls."""
    chip = _chip(v)
    out: list[tuple[str, int]] = []
    for name in ("HOLD", "RUN", "ACC", "DEC"):
        if f"KVAL_{name}" in chip.registers:
            out.append((f"KVAL_{name}", getattr(v, f"kval_{name.lower()}")))
        else:
            out.append((f"TVAL_{name}", getattr(v, f"tval_{name.lower()}")))
    out.append(("OCD_TH", v.ocd_th))
    if "STALL_TH" in chip.registers:
        out.append(("STALL_TH", v.stall_th))
    return tuple(out)


def driver_spec(motor: MotorEntry) -> DspinSpec | None:
    """The DspinSpec of a [[motors]] entry (a MotorConfig), None without [motors.dspin]."""
    v: DspinAxisConfig | None = motor.section(DspinAxisConfig)
    if v is None:
        return None
    return DspinSpec(
        spi=v.spi,
        position=v.position,
        chip=v.driver,
        steps_per_full=v.microsteps,
        registers=registers(v),
        switch=v.switch,
        spi_speed_hz=v.spi_speed_hz,
        hiz_at_exit=v.hiz_at_exit,
        flag=v.flag,
        busy=v.busy,
        rotary=motor.steps_per_rev > 0,
    )


def _microsteps(v: Mapping[str, Any]) -> Violation | None:
    d = v["dspin"]
    if d is None:
        return None
    try:
        _chip(d).step_sel(d.microsteps)
    except ValueError as exc:
        return ("dspin.microsteps", d.microsteps, str(exc))
    return None


def _microsteps_agree(v: Mapping[str, Any]) -> Violation | None:
    d, own = v["dspin"], v["microsteps"]
    if d is not None and own is not None and own != d.microsteps:
        return (
            "microsteps",
            own,
            f"the motor's [motors.dspin] table sets microsteps = {d.microsteps}: write it "
            "once, in [motors.dspin]",
        )
    return None


def _widths(v: Mapping[str, Any]) -> Violation | None:
    d = v["dspin"]
    if d is None:
        return None
    chip = _chip(d)
    for name, value in registers(d):
        reg = chip.registers[name]
        if value > reg.mask:
            key = f"dspin.{name.lower()}"
            return (key, value, f"the {chip.name}'s {name} is {reg.bits} bits: 0..{reg.mask}")
    return None


def _soft_limits(v: Mapping[str, Any]) -> Violation | None:
    d = v["dspin"]
    if d is None:
        return None
    lo, hi = DspinSpec(d.spi, d.position, d.driver, d.microsteps).counter_range or (0, 0)
    for key in ("soft_limit_min", "soft_limit_max"):
        limit = v[key]
        if limit is not None and not lo <= limit <= hi:
            return (
                key,
                limit,
                f"beyond the dSPIN's ABS_POS ({lo}..{hi}, 22 bits of microsteps): the chip "
                "cannot count to it",
            )
    return None


def _one_turn(v: Mapping[str, Any]) -> Violation | None:
    """A rotary axis's MoveTo goes less than one revolution: one GoTo_DIR of the chip goes
    less than one turn of its counter (2^22 microsteps)."""
    spr = v["steps_per_rev"]
    if v["dspin"] is not None and spr > ABS_POS_SPAN:
        return (
            "steps_per_rev",
            spr,
            f"more than a dSPIN's GoTo_DIR goes in one command ({ABS_POS_SPAN} microsteps, "
            "once round ABS_POS's 22 bits): fewer microsteps or a smaller revolution",
        )
    return None


def _stall_homing(v: Mapping[str, Any]) -> Violation | None:
    """Stall homing needs the chip's stall detection and no switch on its SW input (which
    would hard-stop the run before the motor stalls)."""
    d = v["dspin"]
    if d is None or str(v["homing"].source) != "stall":
        return None
    chip = _chip(d)
    if "STALL_TH" not in chip.registers:
        return (
            "homing.source",
            "stall",
            f"the {chip.name} has no stall detection (no STALL_TH, no STEP_LOSS flags): "
            'home it on its SW input, source = "endstop"',
        )
    if d.switch != "none":
        return (
            "homing.source",
            "stall",
            f'[motors.dspin] switch = "{d.switch}": the switch on the chip\'s SW input would '
            'stop the run before the motor stalls; set switch = "none" for stall homing',
        )
    return None


def _not_tmc_too(v: Mapping[str, Any]) -> Violation | None:
    if v["dspin"] is not None and v.get("tmc") is not None:
        return ("dspin", "[motors.dspin]", "the motor also has a [motors.tmc]: one driver chip")
    return None


def _chains(v: Mapping[str, Any]) -> Violation | None:
    """Each chain's positions run 0..N-1, one motor each, one SPI clock."""
    found: dict[str, list[tuple[int, DspinAxisConfig]]] = {}
    for i, m in enumerate(v["motors"]):
        d = m.section(DspinAxisConfig)
        if d is not None:
            found.setdefault(d.spi, []).append((i, d))
    for node, members in found.items():
        seen: dict[int, int] = {}
        for i, d in members:
            if d.position in seen:
                return (
                    f"motors[{i}].dspin.position",
                    d.position,
                    f"also the position of motors[{seen[d.position]}] in the chain on {node}: "
                    "one motor per chip",
                )
            seen[d.position] = i
            first_i, first = members[0]
            if d.spi_speed_hz != first.spi_speed_hz:
                return (
                    f"motors[{i}].dspin.spi_speed_hz",
                    d.spi_speed_hz,
                    f"motors[{first_i}] on the same chain ({node}) says {first.spi_speed_hz}: "
                    "a chain has one clock",
                )
        n = len(members)
        for i, d in members:
            if d.position >= n:
                return (
                    f"motors[{i}].dspin.position",
                    d.position,
                    f"the chain on {node} has {n} chip(s) configured: positions 0..{n - 1}, "
                    "every chip of a chain is configured (give each one a motor)",
                )
    return None


def _lines(v: Mapping[str, Any]) -> Violation | None:
    """A FLAG or BUSY line serves one chain (its chips may share it: wired-OR), and one
    of the two outputs."""
    seen: dict[str, tuple[str, str, int]] = {}  # line -> (output, chain, motor)
    for i, m in enumerate(v["motors"]):
        d = m.section(DspinAxisConfig)
        if d is None:
            continue
        for output in ("flag", "busy"):
            line = getattr(d, output)
            if not line:
                continue
            other = seen.setdefault(line, (output, d.spi, i))
            if other[0] != output:
                return (
                    f"motors[{i}].dspin.{output}",
                    line,
                    f"also the {other[0].upper()} line of motors[{other[2]}]: a line used "
                    "twice (FLAG and BUSY each need a line of their own)",
                )
            if other[1] != d.spi:
                return (
                    f"motors[{i}].dspin.{output}",
                    line,
                    f"also the {output.upper()} line of motors[{other[2]}] on another chain "
                    f"({other[1]}): a line used twice (a line is wired-OR within one chain)",
                )
    return None


@section("Settings of the dSPIN layer shared by every chip (used only with dSPIN chips).")
@dataclass(frozen=True)
class DspinConfig:
    """[dspin]: how the chip-ramp executor watches the dSPIN motors."""

    ramp_poll_ms: float = number(
        5.0, 0.5, 1000.0, "ABS_POS/SPEED/STATUS read period while a motor moves."
    )
    ramp_idle_poll_ms: float = number(
        50.0, 1.0, 10000.0, "The same at rest (GetAbsPos reads the last read)."
    )


class DspinDeclaration(LayerDeclaration):
    """The dSPIN layer: its section; it applies to a spec with a dSPIN chip on any motor."""

    def sections(self) -> tuple[Extension, ...]:
        return (
            Extension(
                "motors",
                "dspin",
                DspinAxisConfig,
                owner="the dSPIN layer (ST dSPIN drivers over SPI)",
                absent=None,
                absent_text="no dSPIN chip",
                rules=(
                    Rule(
                        ("dspin.microsteps", "dspin.driver"),
                        "a power of two the chip can do (1..128; current mode 1..16)",
                        _microsteps,
                    ),
                    Rule(
                        ("microsteps", "dspin.microsteps"),
                        "the same where both are written",
                        _microsteps_agree,
                    ),
                    Rule(
                        ("dspin.ocd_th", "dspin.stall_th"),
                        "within the chip's register",
                        _widths,
                    ),
                    Rule(("dspin",), "not with [motors.tmc] on the same motor", _not_tmc_too),
                    Rule(
                        ("steps_per_rev", "dspin"),
                        f"at most {ABS_POS_SPAN} (ABS_POS's 22 bits) on a dSPIN motor",
                        _one_turn,
                    ),
                    Rule(
                        ("homing.source", "dspin"),
                        "stall only on a chip with stall detection and no switch on SW",
                        _stall_homing,
                    ),
                    Rule(
                        ("soft_limit_min", "soft_limit_max", "dspin"),
                        "within ABS_POS's -2097152..2097151 on a dSPIN motor",
                        _soft_limits,
                    ),
                ),
            ),
            Extension(
                "",
                "dspin",
                DspinConfig,
                owner="the dSPIN layer (ST dSPIN drivers over SPI)",
                rules=(
                    Rule(
                        ("dspin",),
                        "a chain's positions run 0..N-1 with one SPI clock",
                        _chains,
                    ),
                    Rule(
                        ("dspin",),
                        "a FLAG or BUSY line serves one output of one chain",
                        _lines,
                    ),
                ),
            ),
        )

    def applies(self, spec: HardwareSpec) -> bool:
        return any(isinstance(a.driver, DspinSpec) for a in spec.axes)

    def driver_spec(self, motor: MotorEntry) -> DspinSpec | None:
        return driver_spec(motor)
