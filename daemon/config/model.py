"""The daemon's configuration model: every core key, declared once.

Over 500 lines on purpose: every core key with its default, bounds and doc, one
dataclass per table; it is declarations only, and the length is their documentation.

Each dataclass below is both the schema of its table and the frozen value the code reads
(`motorctl.schema`): a field's helper call holds the key's default, bounds and doc. Sections
owned elsewhere (a HAL backend's tables; [step_thread], the step executors', in
motion/executors/config.py) are not here: they are declared next to their owner
and attached at load time (`motorctl.daemon.config.loader.schema`).

Adding a key: add one field to the dataclass of its table, then regenerate the docs
(`python -m motorctl.daemon.config.docs --write`). Adding a core table: declare a dataclass
with `@section(...)` and give `Config` a `table(...)` field for it. A backend's table: see
`motorctl.hal.registry`.

Pure declarations: no state, no I/O; built once per load on the loading thread.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from motorctl.hal.spec import AxisSpec, PinSpec
from motorctl.motion.executors.config import StepThreadConfig
from motorctl.motion.types import HomingSource
from motorctl.protocol.codec import FRAME_GAP_MS, POS_MAX, POS_MIN, WAYPOINTS, CodecOptions
from motorctl.protocol.crc import (
    CHECKSUM_DEFAULT,
    CHECKSUM_TEXT,
    checksum_by_name,
    checksum_names,
)
from motorctl.schema import (
    REQUIRED,
    Rule,
    Sectioned,
    Violation,
    boolean,
    choice,
    extension_sections,
    given,
    integer,
    number,
    section,
    table,
    tables,
    text,
)


def _check_checksum(value: str) -> str | None:
    """Problem with a checksum name, or None when it is usable."""
    try:
        checksum_by_name(value)
    except ValueError:
        return "unknown CRC-8 name"
    return None


@section(
    "Framing and checksum of the UART protocol.",
    prose="The UART protocol's framing and checksum (PROTOCOL.md §1 and §2).",
    notes="""\
`checksum` names any CRC-8 of the reveng catalogue, or one of the catalogue's aliases
({crc_aliases}):
{crc_names}

`"crc8"` is the protocol's default, CRC-8/SMBUS. With `"none"` the checksum byte is ignored
on input and sent as 0x00, so a corrupted frame can be executed: use it only for hosts that
cannot compute a CRC. Names are case-insensitive, as for the client's `--checksum`. An
unknown name is an error that lists the accepted names.""",
)
@dataclass(frozen=True)
class LinkConfig:
    """[link]: framing and checksum of the UART protocol."""

    frame_gap_ms: float = number(
        FRAME_GAP_MS,
        0,
        10000,
        "Longest silence between two bytes of one frame; a longer gap discards the "
        "partial frame (framing error). 0 turns the gap rule off.",
    )
    checksum: str = text(
        CHECKSUM_DEFAULT,
        'Checksum byte B9 / R4. "none": ignored on input, sent as 0x00.',
        check=_check_checksum,
        check_listing=checksum_names,
        check_text=CHECKSUM_TEXT,
    )
    crc_covers_ack: bool = boolean(
        CodecOptions.crc_covers_ack, "true: the response CRC covers R0..R3, not R1..R3."
    )
    strict_padding: bool = boolean(
        CodecOptions.strict_padding,
        "true: a non-zero padding byte gets E1; false accepts any padding.",
    )
    held_frames: int = integer(
        16,
        1,
        1024,
        "Frames kept in arrival order while a WaitMoved response is held; "
        "beyond that each gets E0.",
    )
    timeout_ms: float = number(
        0.0,
        0,
        3600000,
        "0 = off (as the original microcontroller). > 0: when the host sends no byte for "
        "this long (while a WaitMoved's answer is held the host is waiting, not silent), "
        "every motor in motion stops (timeout_action) and answers E4 until a StopMove "
        "clears it; motors at rest are not touched; the DC motor brakes. Above 0 it must "
        "be at least one frame's time at --baud (0.868 ms at 115200; the daemon and "
        "--check-config refuse less). An extension: docs/protocol.md, 'When the host "
        "falls silent'.",
    )
    timeout_action: str = choice(
        "decelerate",
        ("decelerate", "hard"),
        "How timeout_ms stops a motor: 'decelerate' along its DEC ramp, as a soft "
        "StopMove; 'hard' at once, as a hard StopMove.",
    )

    def codec_options(self) -> CodecOptions:
        """The codec settings this table selects (crc None for checksum "none")."""
        from motorctl.protocol.codec import CodecOptions

        return CodecOptions(
            crc=checksum_by_name(self.checksum),
            crc_covers_ack=self.crc_covers_ack,
            strict_padding=self.strict_padding,
        )


@section(
    "Factors from protocol bytes to step/s and step/s^2.",
    prose="""\
Factors that turn the protocol's SPEED, ACC and DEC bytes into step/s and step/s^2
(PROTOCOL.md §3). A byte of 0 always means the motor's configured default, and a result
above the motor's maximum is clamped, never refused.""",
)
@dataclass(frozen=True)
class UnitsConfig:
    """[units]: protocol byte -> physical unit factors."""

    run_speed_factor: float = number(
        4096.0, 0, 1e6, "step/s per SPEED unit for InitMove and Move.", lo_open=True
    )
    move_speed_factor: float = number(
        4.0, 0, 1e6, "step/s per SPEED unit for MoveTo and MoveToWayPoint.", lo_open=True
    )
    accel_factor: float = number(16.0, 0, 1e7, "step/s^2 per ACC / DEC unit.", lo_open=True)


def _backend_names() -> tuple[str, ...]:
    from motorctl.hal.registry import BACKENDS

    return tuple(BACKENDS)


def _backend_note() -> str:
    if len(_backend_names()) == 1:
        return "the only backend in this version"
    return "the backends of motorctl.hal.registry"


@section(
    "Hardware backend.",
    prose="""\
The backend drives the outputs and reads the inputs. Each backend owns a config section of
its own (its tables are marked with the backend's name below); every registered backend's
section is checked, whichever backend is chosen, and only the chosen backend's hardware
library is loaded.""",
)
@dataclass(frozen=True)
class HalConfig:
    """[hal]: which hardware backend drives the outputs."""

    backend: str = choice(
        "mock",
        _backend_names,
        'Hardware backend; "mock" simulates motors, end stops and wired pins.',
        note=_backend_note,
    )


@section(
    "The DC motor. Absent: no DC motor (DcMove answers E2). Present, even empty: a DC motor.",
    prose="""\
Leave the table out for a machine without a DC motor: DcMove then answers E2. A `[dc]`
line on its own (an empty table) configures a DC motor with the defaults below.""",
    notes="""\
GO_HiZ TRUE leaves the bridge in high impedance (coasting) after the run, FALSE brakes it,
as the field's name says (PROTOCOL.md §4); `invert_hiz = true` swaps the two for hosts
written against the original's prose.""",
)
@dataclass(frozen=True)
class DcConfig:
    """[dc]: the DC motor (only present when configured)."""

    invert_hiz: bool = boolean(False, "true inverts the meaning of DcMove's GO_HiZ byte.")
    max_time_ms: int = integer(65535, 1, 65535, "Cap for the TIME of one run.")


@section("How InitMove finds the end stop, and zero off it (docs/protocol.md, Homing).")
@dataclass(frozen=True)
class HomingConfig:
    """[motors.homing]: how InitMove finds the end stop."""

    source: HomingSource = choice(
        HomingSource.ENDSTOP,
        HomingSource,
        "What stops homing: the end-stop input, or the driver's stall flag.",
    )
    speed: float = number(
        2000.0, 0, "max_speed", "step/s used when InitMove's SPEED = 0.", lo_open=True
    )
    max_travel: int = integer(
        40000, 1, POS_MAX - POS_MIN, "Steps; no trigger (or release) within them -> fault."
    )
    pull_off: int = integer(
        0,
        0,
        1000000,
        "0 = one-phase homing; > 0 = back off this many steps after the first trigger "
        "and re-approach at second_speed.",
    )
    second_speed: float = number(
        250.0, 0, "max_speed", "step/s of the slow re-approach and release.", lo_open=True
    )


@section("The end-stop input.")
@dataclass(frozen=True)
class EndstopConfig:
    """[motors.endstop]: the end-stop input."""

    active_low: bool = boolean(False, "true: the input is active when it reads low.")
    debounce_ms: float = number(
        0.0, 0, 1000, "The input must read active this long before it counts."
    )


def _soft_limits_paired(v: Mapping[str, Any]) -> Violation | None:
    lo, hi = v["soft_limit_min"], v["soft_limit_max"]
    if lo is not None and hi is None:
        return ("soft_limit_min", lo, "soft_limit_max is not set")
    if hi is not None and lo is None:
        return ("soft_limit_max", hi, "soft_limit_min is not set")
    return None


def _soft_limits_ordered(v: Mapping[str, Any]) -> Violation | None:
    lo, hi = v["soft_limit_min"], v["soft_limit_max"]
    if lo is not None and hi is not None and lo >= hi:
        return ("soft_limit_min", lo, f"not below soft_limit_max = {hi}")
    return None


def _soft_limits_linear(v: Mapping[str, Any]) -> Violation | None:
    spr = v["steps_per_rev"]
    if spr > 0:
        for key in ("soft_limit_min", "soft_limit_max"):
            if v[key] is not None:
                return (key, v[key], f"soft limit on a rotary axis (steps_per_rev = {spr})")
    return None


_SOFT_LIMITS = ("soft_limit_min", "soft_limit_max")


def _microsteps_power_of_two(v: Mapping[str, Any]) -> Violation | None:
    n = v["microsteps"]
    if n is not None and n & (n - 1):
        return ("microsteps", n, "not a power of two")
    return None


#: a motor's microsteps per full step when neither its config nor its driver chip's says
MICROSTEPS_UNSAID = 16


@section(
    "Stepper motors, numbered 0..N-1 in file order.",
    rules=(
        Rule(
            _SOFT_LIMITS,
            "set both soft_limit_min and soft_limit_max, or neither",
            _soft_limits_paired,
        ),
        Rule(_SOFT_LIMITS, "soft_limit_min < soft_limit_max", _soft_limits_ordered),
        Rule(_SOFT_LIMITS, "only on a linear axis (steps_per_rev = 0)", _soft_limits_linear),
        Rule(("microsteps",), "a power of two: 1, 2, 4, ..., 256", _microsteps_power_of_two),
    ),
    prose="""\
One `[[motors]]` table per stepper motor, numbered 0, 1, ... N-1 in file order: that number
is the protocol's MOTOR byte. At least one is required, at most 64. A `[motors.homing]`,
`[motors.endstop]` or backend table (`[motors.mock]`...) written after a `[[motors]]` line
belongs to that motor; left out, it takes its defaults.""",
    notes="""\
Notes:

- `max_speed`, `max_accel`: a SPEED, ACC or DEC byte whose value exceeds them is clamped
  (and counted), never refused.
- `default_speed`, `homing.speed` and `homing.second_speed` must not exceed the same
  motor's `max_speed`; `default_accel` and `default_decel` must not exceed its `max_accel`.
- Soft limits are positions in steps; both or neither, `soft_limit_min < soft_limit_max`,
  and only on a linear axis (on a rotary axis every position in `[0, steps_per_rev)` is
  reachable).
- `homing.max_travel` counts the steps of one homing run; without a trigger by then the
  motor faults (E4 until StopMove clears it). With `pull_off > 0` homing backs off that far
  after the first trigger and approaches again at `second_speed`. After the (last) trigger it
  backs off at `second_speed` (at most InitMove's speed; it ends with a stop without ramp)
  until the end stop releases, at most `max_travel` steps, else it faults: 0 is there.
- `microsteps`, `max_lag_full_steps`, `start_speed`: how a late step is judged
  (docs/timing.md). A step the executor makes late slides the rest of that motor's move by
  its lateness; it stops the motor with E4 "step timing lost" (position lost) only when the
  motor runs faster than `start_speed` and the lag, lateness x step rate / `microsteps`, is
  more than `max_lag_full_steps` full steps. A motor with a `[motors.tmc]` table takes its
  microsteps from there (writing both with different values is an error). The mock
  backend's motors never lose steps unless `[mock] lose_steps = true`.""",
)
@dataclass(frozen=True)
class MotorConfig(Sectioned):
    """One [[motors]] entry; its index in Config.motors is its protocol number."""

    name: str = text(
        "motor{index}",
        "Name used in logs and tools.",
        pattern=r"[A-Za-z0-9_.-]{1,64}",
        pattern_text="1..64 letters, digits, '_', '-' or '.'",
        unique=True,
        indexed_default=True,
        default_text='"motor0", "motor1", ... (by index)',
    )
    steps_per_rev: int = integer(
        0, 0, POS_MAX, "0 = linear axis; > 0 = rotary axis, position kept in [0, steps_per_rev)."
    )
    invert_dir: bool = boolean(
        AxisSpec.invert_dir, "Swap the DIR wiring (not the protocol's direction)."
    )
    max_speed: float = number(
        25000.0, 0, 200000, "step/s; faster requests are clamped.", lo_open=True
    )
    max_accel: float = number(
        200000.0, 0, 1e7, "step/s^2; larger ACC / DEC are clamped.", lo_open=True
    )
    start_speed: float = number(
        100.0,
        0,
        200000,
        "step/s the motor can start or stop at without a ramp: stopped by a 'step timing "
        "lost' fault from above it, its position counts as lost (home it again).",
    )
    microsteps: int | None = integer(
        None,
        1,
        256,
        "Microsteps per full step the driver is set to (a power of two): a late step's lag "
        "is judged in full steps.",
        optional=True,
        default_text=f"the [motors.tmc] table's microsteps, else {MICROSTEPS_UNSAID}",
    )
    max_lag_full_steps: float = number(
        0.5,
        0,
        64,
        "Above start_speed, a late step whose lag (lateness x step rate / microsteps) is more "
        "than this many full steps stops the motor: E4 'step timing lost', position lost. "
        "Within it the move slides (takes longer by the lateness). 0.5: a motor's torque "
        "peaks when its rotor lags the field by one full step and it slips (by 4 full steps) "
        "beyond two; the load already takes part of that, so a pause may add half a step.",
        lo_open=True,
    )
    default_speed: float = number(
        2000.0, 0, "max_speed", "step/s used when SPEED = 0, and by GoHome.", lo_open=True
    )
    default_accel: float = number(
        8000.0, 0, "max_accel", "step/s^2 used when ACC = 0.", lo_open=True
    )
    default_decel: float = number(
        8000.0, 0, "max_accel", "step/s^2 used when DEC = 0.", lo_open=True
    )
    queue_depth: int = integer(
        16, 1, 1024, "Motion commands that may wait behind the one executing; more -> E0."
    )
    max_waypoints: int = integer(WAYPOINTS, 1, WAYPOINTS, "Size of the waypoint table; more -> E5.")
    soft_limit_min: int | None = integer(
        None,
        POS_MIN,
        POS_MAX,
        "Lowest allowed target; a MoveTo outside the limits -> E1, a Move stops at them.",
        optional=True,
        default_text="unset",
    )
    soft_limit_max: int | None = integer(
        None, POS_MIN, POS_MAX, "Highest allowed target.", optional=True, default_text="unset"
    )
    homing: HomingConfig = table(HomingConfig)
    endstop: EndstopConfig = table(EndstopConfig)
    sections: Mapping[type[Any], Any] = extension_sections()

    @property
    def rotary(self) -> bool:
        """True for a rotary axis (steps_per_rev > 0)."""
        return self.steps_per_rev > 0


@section(
    "IO pins the host addresses by PIN_NR; no other pin is reachable.",
    prose="""\
One `[[pins]]` table per IO pin the host may use, addressed by its PIN_NR. Any other PIN_NR
answers E2. Without `[[pins]]` there are none.""",
    notes="""\
`initial` and `safe` are output levels (`true` = high). They also apply to a pin configured
as an input, should the host switch it to an output with ConfigPin.""",
)
@dataclass(frozen=True)
class PinConfig(Sectioned):
    """One [[pins]] entry: a pin the host may address by PIN_NR."""

    number: int = integer(REQUIRED, 0, 255, "The host's PIN_NR.", unique=True)
    mode: str = choice("output", ("output", "input"), "Direction at start (ConfigPin changes it).")
    initial: bool = boolean(PinSpec.initial, "Output level at start (true = high).")
    safe: bool = boolean(False, "Output level set at shutdown (true = high).")
    sections: Mapping[type[Any], Any] = extension_sections()

    @property
    def is_output(self) -> bool:
        """True when the pin starts as an output."""
        return self.mode == "output"


def _check_state_dir(value: str) -> str | None:
    """Problem with a state directory, or None: empty or an absolute path (one the system
    can take: no NUL character)."""
    if value == "":
        return None
    if not value.startswith("/"):
        return "not an absolute path"
    if "\0" in value:
        return "holds a NUL character (\\u0000), which no path can"
    return None


def names_a_folder(path: str) -> bool:
    """Whether ``path`` is written as a folder's: empty, or its last part ``''`` (a trailing
    ``/``), ``.`` or ``..``. A file the daemon makes there would be that folder, which it
    would set aside as in its way (and ``Path`` forgets a trailing ``/``)."""
    return path.rsplit("/", 1)[-1] in ("", ".", "..")


def _check_trace_file(value: str) -> str | None:
    """Problem with a trace file name, or None: empty or an absolute path of a file (not
    one written as a folder's: :func:`names_a_folder`)."""
    problem = _check_state_dir(value)
    if problem is None and value and names_a_folder(value):
        return "names a folder, not a file"
    return problem


@section(
    "Where home positions, waypoints and positions at rest are kept.",
    prose="""Where the state file (home positions, waypoints, positions of motors at rest) and its
motion journal live. By default in the runtime directory given by `--state-dir`
(/run/motorctl under systemd): it survives a restart of the daemon and is gone after a
reboot, like a microcontroller's RAM (PROTOCOL.md §4). docs/service.md says when to keep
it across reboots instead.""",
    notes="""`directory = "/var/lib/motorctl"` keeps the state across reboots (the packaged unit has
`StateDirectory=motorctl`, so that directory exists and is writable for the service).
Do that only when nothing moves the axes while the board is off: after a reboot the
daemon trusts the saved positions of motors that were at rest.""",
)
@dataclass(frozen=True)
class StateConfig:
    """[state]: where the state file lives."""

    directory: str = text(
        "",
        'Directory of state.json and state.moving; "" = the --state-dir (runtime directory).',
        check=_check_state_dir,
        check_text='"" or an absolute path',
    )


@section(
    "A trace of every byte run on the link, for `motorctl trace` and `motorctl replay`.",
    prose="""\
A trace of the link: every byte run the daemon reads from the host or writes to it, with a
timestamp and its direction, in the pcapng format the tap writes too (docs/trace.md).
`motorctl trace FILE` prints it decoded; `motorctl replay FILE --port P` plays its host side
against a device; Wireshark and tshark open it. Off unless `file` is set here or
`motorctld --trace FILE` is given (the option wins).""",
    notes="""\
The trace is bounded: when the file would grow past `max_file_mb` it is renamed to
`FILE.1` (an older `FILE.1` to `FILE.2`, ...) and a new `FILE` is started, keeping `files`
files in all; the oldest goes. Each file names the daemon's run (its session) and its part
number (1, 2, ...), so `motorctl trace` and `motorctl replay` say which parts are missing.
Records are written from memory every 0.2 s by a thread of
their own; if the disk falls that far behind that 4 MiB wait, further byte runs are left
out and counted (`trace.dropped_runs` in the status, `epb_dropcount` in the file). Under
systemd the service may write only below /run/motorctl and /var/lib/motorctl.""",
)
@dataclass(frozen=True)
class TraceConfig:
    """[trace]: the link's byte runs to a pcapng file."""

    file: str = text(
        "",
        'Trace file; "" = no trace (motorctld --trace FILE sets it too).',
        check=_check_trace_file,
        check_text='"" or an absolute path',
    )
    max_file_mb: float = number(16.0, 0.01, 1e6, "Size of one file (MiB) before it rotates.")
    files: int = integer(4, 1, 1000, "Files kept, the current one included.")


@section("The whole file.")
@dataclass(frozen=True)
class Config(Sectioned):
    """The whole validated configuration; `source` is the file it came from."""

    link: LinkConfig = table(LinkConfig)
    units: UnitsConfig = table(UnitsConfig)
    hal: HalConfig = table(HalConfig)
    step_thread: StepThreadConfig = table(StepThreadConfig)
    state: StateConfig = table(StateConfig)
    trace: TraceConfig = table(TraceConfig)
    dc: DcConfig | None = table(DcConfig, absent=None, absent_text="no DC motor")
    motors: tuple[MotorConfig, ...] = tables(
        MotorConfig, 1, 64, absent=REQUIRED, absent_text="required"
    )
    pins: tuple[PinConfig, ...] = tables(PinConfig, 0, 256, absent=[], absent_text="no pins")
    sections: Mapping[type[Any], Any] = extension_sections()
    source: str = given("")
    #: what the file wrote that is retired (each names the key and why): logged at start
    notices: tuple[str, ...] = given((), compare=False)
