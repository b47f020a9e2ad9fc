"""The TMC layer's declaration (:class:`TmcDeclaration`, hal/contract.py): its config
sections, [motors.tmc] per motor and [spidev] globally, the chips by the names
``[motors.tmc] driver`` takes (:data:`CHIPS`), and the driver spec a motor's [motors.tmc]
gives it.

The layer works with every hardware backend (it replaces a motor's driver status with a
TMC2130/TMC5160 read over /dev/spidevB.C), so it is named in
`motorctl.hal.registry.LAYERS`, not as a backend. Like every declaration it imports no
hardware library: a config is checked without py-spidev.

Each key's default is the runtime record's (:class:`TmcSettings`, :class:`TmcSpec` in
settings.py), read from there and written nowhere else; tests/daemon/test_config_defaults.py
fails on a default written twice.

Pure declarations and conversions: no state, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, Final

from motorctl.hal.contract import ChipTable, LayerDeclaration, MotorEntry
from motorctl.hal.interfaces import RampDriver
from motorctl.hal.layers.tmc.fields import Chip, mres_of
from motorctl.hal.layers.tmc.settings import TmcSettings, TmcSpec
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


def _chips() -> dict[str, Chip]:
    from motorctl.hal.layers.tmc.tmc2130 import TMC2130
    from motorctl.hal.layers.tmc.tmc5160 import TMC5160

    return {c.name.lower(): c for c in (TMC2130, TMC5160)}


#: the chips the layer knows, by the name ``[motors.tmc] driver`` takes (their modules
#: imported when one is asked for: a config without a TMC motor imports none of them)
CHIPS: Final[Mapping[str, Chip]] = ChipTable(("tmc2130", "tmc5160"), _chips)


@section(
    "A Trinamic TMC2130 or TMC5160 driver on SPI (absent: no driver chip to talk to).",
    notes="""\
The chip is checked at start: IOIN's version must match `driver` (else the daemon refuses to
start, naming the device and what it found); GCONF, CHOPCONF (TOFF, MRES, ...), IHOLD_IRUN,
TPOWERDOWN, TCOOLTHRS and COOLCONF (stallGuard threshold) are written, each write is
verified by the chip's echo and the readable ones are read back. While running, the HAL's
driver poller reads DRV_STATUS every `[drivers] poll_ms`: over-temperature, shorts to ground
or supply and (while moving) open load fault the motor (E4); a short also switches the
bridges off until motorctld restarts. The stall flag counts only while moving faster than
`stall_min_speed`. `mode = "ramp"` (TMC5160 only, SD_MODE tied low) lets the chip's own
ramp generator move the motor: no STEP/DIR lines, positions are XACTUAL, homing uses the
chip's REFL/REFR inputs (`homing.source = "endstop"`) or stallGuard (`"stall"`, needs
`stall_min_speed > 0`). Currents are RMS amperes, converted with the sense resistor by the
datasheet's formula.""",
    retired={
        "poll_ms": "the HAL's one driver poller reads every driver chip now and hands a "
        "fault to the motors as it reads it; its period, for every chip, is [drivers] poll_ms",
    },
)
@dataclass(frozen=True)
class TmcAxisConfig:
    """[motors.tmc]: one motor's driver chip."""

    driver: str = choice("tmc2130", tuple(CHIPS), "The chip: its IOIN version is checked.")
    spi: str = text(
        DEFAULT_DEVICE,
        "The SPI device: bus B, chip select C.",
        pattern=DEVICE_PATTERN,
        pattern_text="/dev/spidevB.C, for example /dev/spidev0.1",
    )
    spi_speed_hz: int = integer(
        TmcSpec.spi_speed_hz,
        10_000,
        4_000_000,
        "SPI clock; the chips accept up to 4 MHz (fCLK/2 or less).",
    )
    mode: str = choice(
        "step_dir",
        ("step_dir", "ramp"),
        "step_dir: STEP/DIR lines move it; ramp: the TMC5160's own ramp generator does.",
    )
    sense_resistor: float = number(
        TmcSettings.sense_resistor,
        0.0,
        1.0,
        "Ohm; 0 = the usual board value (TMC2130 0.11, TMC5160 0.075).",
    )
    run_current: float = number(
        TmcSettings.run_current, 0.0, 20.0, "A rms while moving.", lo_open=True
    )
    hold_current: float = number(
        TmcSettings.hold_current, 0.0, "run_current", "A rms at standstill."
    )
    hold_delay: int = integer(
        TmcSettings.hold_delay, 0, 15, "IHOLDDELAY: how gradually run falls to hold current."
    )
    microsteps: int = integer(
        TmcSettings.microsteps,
        1,
        256,
        "Microsteps per full step (a power of two); one step of the protocol is one microstep.",
    )
    interpolate: bool = boolean(TmcSettings.interpolate, "intpol: interpolate to 256 microsteps.")
    toff: int = integer(
        TmcSettings.toff, 1, 15, "CHOPCONF.TOFF (off time); the driver is off only at exit."
    )
    hstrt: int = integer(TmcSettings.hstrt, 0, 7, "CHOPCONF.HSTRT (hysteresis start).")
    hend: int = integer(TmcSettings.hend, 0, 15, "CHOPCONF.HEND (hysteresis end).")
    tbl: int = integer(TmcSettings.tbl, 0, 3, "CHOPCONF.TBL (blank time).")
    stealthchop: bool = boolean(
        TmcSettings.stealthchop, "en_pwm_mode: stealthChop (stallGuard needs spreadCycle)."
    )
    tpowerdown: int = integer(
        TmcSettings.tpowerdown, 0, 255, "TPOWERDOWN: standstill delay before hold current."
    )
    stall_threshold: int = integer(
        TmcSettings.stall_threshold,
        -64,
        63,
        "COOLCONF.SGT: stallGuard threshold; higher = less sensitive.",
    )
    stall_filter: bool = boolean(
        TmcSettings.stall_filter, "COOLCONF.SFILT: filter stallGuard over 4 full steps."
    )
    stall_min_speed: float = number(
        TmcSettings.stall_min_speed,
        0.0,
        1e6,
        "step/s; below it the stall flag is ignored (TCOOLTHRS); 0 = always.",
    )
    clock_hz: float = number(
        TmcSettings.clock_hz, 4e6, 18e6, "fCLK: 12 MHz internal unless CLK is driven."
    )
    open_load: str = choice(
        TmcSettings.open_load,
        ("fault", "warn", "ignore"),
        "What open load (checked in motion) does.",
    )
    ref_left_active_low: bool = boolean(
        TmcSpec.ref_left_active_low, "ramp mode: REFL is active when low."
    )
    ref_right_active_low: bool = boolean(
        TmcSpec.ref_right_active_low, "ramp mode: REFR is active when low."
    )
    disable_at_exit: bool = boolean(
        TmcSpec.disable_at_exit, "TOFF = 0 when motorctld exits (motor unpowered)."
    )


#: the keys of [motors.tmc] a TmcSettings holds as they are (its chip and shaft are derived)
_AS_WRITTEN: Final = tuple(
    f.name for f in fields(TmcSettings) if f.name not in ("chip", "invert_dir")
)


def _settings(v: TmcAxisConfig, invert_dir: bool) -> TmcSettings:
    return TmcSettings(
        chip=CHIPS[v.driver],
        invert_dir=invert_dir and v.mode == "ramp",  # step/dir: the DIR line is inverted
        **{name: getattr(v, name) for name in _AS_WRITTEN},
    )


def driver_spec(motor: MotorEntry) -> TmcSpec | None:
    """The TmcSpec of a [[motors]] entry (a MotorConfig), None without [motors.tmc]."""
    v: TmcAxisConfig | None = motor.section(TmcAxisConfig)
    if v is None:
        return None
    return TmcSpec(
        spi=v.spi,
        settings=_settings(v, bool(motor.invert_dir)),
        spi_speed_hz=v.spi_speed_hz,
        ramp=v.mode == "ramp",
        ref_left_active_low=v.ref_left_active_low,
        ref_right_active_low=v.ref_right_active_low,
        disable_at_exit=v.disable_at_exit,
    )


def _ramp_needs_tmc5160(v: Mapping[str, Any]) -> Violation | None:
    t = v["tmc"]
    if t is not None and t.mode == "ramp" and t.driver != "tmc5160":
        return ("tmc.mode", t.mode, f"the ramp generator is a TMC5160's; driver is {t.driver}")
    return None


def _microsteps(v: Mapping[str, Any]) -> Violation | None:
    t = v["tmc"]
    if t is None:
        return None
    try:
        mres_of(t.microsteps)
    except ValueError:
        return ("tmc.microsteps", t.microsteps, "not a power of two")
    return None


def _microsteps_agree(v: Mapping[str, Any]) -> Violation | None:
    t, own = v["tmc"], v["microsteps"]
    if t is not None and own is not None and own != t.microsteps:
        return (
            "microsteps",
            own,
            f"the motor's [motors.tmc] table sets microsteps = "
            f"{t.microsteps}: write it once, in [motors.tmc]",
        )
    return None


def _current(v: Mapping[str, Any]) -> Violation | None:
    t = v["tmc"]
    if t is None:
        return None
    chip = CHIPS[t.driver]
    try:
        chip.current_setting(
            t.sense_resistor or chip.default_sense_ohm, t.run_current, t.hold_current
        )
    except ValueError as exc:
        return ("tmc.run_current", t.run_current, str(exc))
    return None


def _ramp_stall_speed(v: Mapping[str, Any]) -> Violation | None:
    t = v["tmc"]
    if t is None or t.mode != "ramp" or str(v["homing"].source) != "stall":
        return None
    if t.stall_min_speed <= 0:
        return (
            "tmc.stall_min_speed",
            t.stall_min_speed,
            "stall homing in ramp mode needs the chip's stallGuard stop, which works only "
            "above TCOOLTHRS: set stall_min_speed > 0",
        )
    return None


@section("Settings of the TMC layer shared by every driver (used only with drivers).")
@dataclass(frozen=True)
class SpidevConfig:
    """[spidev]: how the TMC5160 ramp executor watches its chips."""

    ramp_poll_ms: float = number(
        RampDriver.poll_s * 1e3,
        0.5,
        1000.0,
        "ramp mode: XACTUAL/RAMP_STAT poll period while a motor moves.",
    )
    ramp_idle_poll_ms: float = number(
        RampDriver.idle_poll_s * 1e3,
        1.0,
        10000.0,
        "ramp mode: the same at rest (GetAbsPos reads the last poll).",
    )


def _devices_unique(v: Mapping[str, Any]) -> Violation | None:
    seen: dict[str, int] = {}
    for i, m in enumerate(v["motors"]):
        t = m.section(TmcAxisConfig)
        if t is None:
            continue
        if t.spi in seen:
            return (
                f"motors[{i}].tmc.spi",
                t.spi,
                f"also the device of motors[{seen[t.spi]}]: one chip per chip select",
            )
        seen[t.spi] = i
    return None


class TmcDeclaration(LayerDeclaration):
    """The TMC layer: its sections; it applies to a spec with a TMC chip on any motor."""

    def sections(self) -> tuple[Extension, ...]:
        return (
            Extension(
                "motors",
                "tmc",
                TmcAxisConfig,
                owner="the TMC layer (TMC drivers over SPI)",
                absent=None,
                absent_text="no driver chip on SPI",
                rules=(
                    Rule(
                        ("tmc.mode", "tmc.driver"),
                        'mode = "ramp" needs driver = "tmc5160"',
                        _ramp_needs_tmc5160,
                    ),
                    Rule(("tmc.microsteps",), "a power of two: 1, 2, 4, ..., 256", _microsteps),
                    Rule(
                        ("microsteps", "tmc.microsteps"),
                        "the same where both are written",
                        _microsteps_agree,
                    ),
                    Rule(
                        ("tmc.run_current", "tmc.sense_resistor"),
                        "a current the chip can drive through this sense resistor",
                        _current,
                    ),
                    Rule(
                        ("tmc.stall_min_speed",),
                        "> 0 for stall homing in ramp mode",
                        _ramp_stall_speed,
                    ),
                ),
            ),
            Extension(
                "",
                "spidev",
                SpidevConfig,
                owner="the TMC layer (TMC drivers over SPI)",
                rules=(Rule(("spidev",), "each SPI device belongs to one motor", _devices_unique),),
            ),
        )

    def applies(self, spec: HardwareSpec) -> bool:
        return any(isinstance(a.driver, TmcSpec) for a in spec.axes)

    def driver_spec(self, motor: MotorEntry) -> TmcSpec | None:
        return driver_spec(motor)
