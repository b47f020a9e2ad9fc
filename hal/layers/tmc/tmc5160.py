"""The TMC5160 (datasheet rev. 1.14): its registers and fields, its :class:`Chip`, and the
driver of its own ramp generator (:class:`Tmc5160`).

Besides what it shares with the TMC2130 (``fields.py``): GLOBALSCALER, the short-to-supply
flags, SD_MODE, the ramp generator's registers (motion-controller mode, SD_MODE low), the
reference switch configuration (SW_MODE) and status (RAMP_STAT), and the conversions
between steps/s, steps/s^2 and the ramp generator's units.

:class:`Tmc5160` is the shared driver (``driver.py``; started, configured and verified like
every driver, its DRV_STATUS polled by the HAL's driver poller) that also sets up and drives the
chip's ramp generator: positioning and velocity mode, hard and soft stops, the reference
switches REFL/REFR (stop and latch XACTUAL into XLATCH on the active edge, or latch it on
the inactive edge: where the switch releases), stallGuard stops, and homing on them (zero
where the switch releases again, or where it stalled: docs/protocol.md, InitMove): the HAL's
:class:`~motorctl.hal.interfaces.RampDriver` capability. A TMC5160 moved by
STEP/DIR is the shared driver alone.

Threads: the data and formulas, any thread. A :class:`Tmc5160`'s ramp calls come from the
thread of the executor that owns the motor (the planner, with the motion engine's lock
held); each is a few SPI datagrams in one bus session.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from motorctl.hal.interfaces import DriverStatus, RampDriver, RampStatus
from motorctl.hal.layers.tmc import fields
from motorctl.hal.layers.tmc.driver import TmcDriver
from motorctl.hal.layers.tmc.fields import (
    DRV_FLAGS,
    SHORTS_TO_GROUND,
    Chip,
    CurrentSetting,
    Field,
    check_currents,
    current_scale,
    register_names,
    signed32,
)
from motorctl.hal.layers.tmc.link import TmcError
from motorctl.hal.layers.tmc.settings import TmcSettings
from motorctl.hal.spi import SpiBus


class Reg(fields.Reg):
    """The shared registers and the TMC5160's own."""

    GLOBALSCALER: Final = 0x0B
    RAMPMODE: Final = 0x20
    XACTUAL: Final = 0x21
    VACTUAL: Final = 0x22
    VSTART: Final = 0x23
    A1: Final = 0x24
    V1: Final = 0x25
    AMAX: Final = 0x26
    VMAX: Final = 0x27
    DMAX: Final = 0x28
    D1: Final = 0x2A
    VSTOP: Final = 0x2B
    TZEROWAIT: Final = 0x2C
    XTARGET: Final = 0x2D
    SW_MODE: Final = 0x34
    RAMP_STAT: Final = 0x35
    XLATCH: Final = 0x36


class F(fields.F):
    """The shared fields and the TMC5160's own, each keyed by its register."""

    SD_MODE: Final = Field(Reg.IOIN, 6)  # 1 = external STEP/DIR, 0 = internal ramp generator
    S2VSA: Final = Field(Reg.DRV_STATUS, 12)
    S2VSB: Final = Field(Reg.DRV_STATUS, 13)
    STEALTH: Final = Field(Reg.DRV_STATUS, 14)
    STOP_L_ENABLE: Final = Field(Reg.SW_MODE, 0)
    STOP_R_ENABLE: Final = Field(Reg.SW_MODE, 1)
    POL_STOP_L: Final = Field(Reg.SW_MODE, 2)
    POL_STOP_R: Final = Field(Reg.SW_MODE, 3)
    LATCH_L_ACTIVE: Final = Field(Reg.SW_MODE, 5)
    LATCH_L_INACTIVE: Final = Field(Reg.SW_MODE, 6)
    LATCH_R_ACTIVE: Final = Field(Reg.SW_MODE, 7)
    LATCH_R_INACTIVE: Final = Field(Reg.SW_MODE, 8)
    SG_STOP: Final = Field(Reg.SW_MODE, 10)
    EN_SOFTSTOP: Final = Field(Reg.SW_MODE, 11)
    STATUS_STOP_L: Final = Field(Reg.RAMP_STAT, 0)
    STATUS_STOP_R: Final = Field(Reg.RAMP_STAT, 1)
    STATUS_LATCH_L: Final = Field(Reg.RAMP_STAT, 2)
    STATUS_LATCH_R: Final = Field(Reg.RAMP_STAT, 3)
    EVENT_STOP_L: Final = Field(Reg.RAMP_STAT, 4)
    EVENT_STOP_R: Final = Field(Reg.RAMP_STAT, 5)
    EVENT_STOP_SG: Final = Field(Reg.RAMP_STAT, 6)
    EVENT_POS_REACHED: Final = Field(Reg.RAMP_STAT, 7)
    VELOCITY_REACHED: Final = Field(Reg.RAMP_STAT, 8)
    POSITION_REACHED: Final = Field(Reg.RAMP_STAT, 9)
    VZERO: Final = Field(Reg.RAMP_STAT, 10)
    VACTUAL: Final = Field(Reg.VACTUAL, 0, 24, signed=True)


#: RAMP_STAT flags that are cleared by writing 1 (datasheet: R+WC)
RAMP_STAT_WC: Final = (
    F.STATUS_LATCH_L.mask
    | F.STATUS_LATCH_R.mask
    | F.EVENT_STOP_SG.mask
    | F.EVENT_POS_REACHED.mask
    | (1 << 12)
)


#: full-scale sense voltage [V] (fixed; GLOBALSCALER scales the current)
VFS: Final = 0.325

VSTOP_MIN: Final = 10  # datasheet: VSTOP >= VSTART, at least 10 recommended in positioning mode


class Tmc5160Chip(Chip):
    """The TMC5160's current scaling: IRUN/IHOLD under GLOBALSCALER, the sense voltage
    fixed."""

    def __reduce__(self) -> str:
        return "TMC5160"  # the module's constant: one chip, the same object everywhere

    @staticmethod
    def full_scale(sense_ohm: float) -> float:
        """The RMS current [A] of current scale 31 at GLOBALSCALER 256."""
        return VFS / sense_ohm / math.sqrt(2)

    def current_setting(self, sense_ohm: float, run_a: float, hold_a: float) -> CurrentSetting:
        check_currents(sense_ohm, run_a, hold_a)
        fs256 = self.full_scale(sense_ohm)
        if run_a > fs256 * 1.0001:
            raise ValueError(
                f"run_current {run_a} A is above the {fs256:.2f} A a TMC5160 gives with a "
                f"{sense_ohm} ohm sense resistor"
            )
        gs = max(32, min(256, math.ceil(256 * run_a / fs256)))
        fs = fs256 * gs / 256
        return CurrentSetting(
            current_scale(run_a, fs), current_scale(hold_a, fs), globalscaler=gs % 256
        )

    def rms(self, setting: CurrentSetting, sense_ohm: float, cs: int) -> float:
        gs = setting.globalscaler or 256
        return gs / 256 * (cs + 1) / 32 * self.full_scale(sense_ohm)

    def scale_registers(self, setting: CurrentSetting, chopconf: int) -> dict[int, int]:
        return {Reg.GLOBALSCALER: setting.globalscaler, Reg.CHOPCONF: chopconf}


TMC5160: Final = Tmc5160Chip(
    name="TMC5160",
    version=0x30,
    readable=frozenset(
        {
            Reg.GCONF,
            Reg.GSTAT,
            Reg.IOIN,
            Reg.TSTEP,
            Reg.RAMPMODE,
            Reg.XACTUAL,
            Reg.VACTUAL,
            Reg.XTARGET,
            Reg.SW_MODE,
            Reg.RAMP_STAT,
            Reg.XLATCH,
            Reg.MSCNT,
            Reg.CHOPCONF,
            Reg.DRV_STATUS,
        }
    ),
    status_bits=8,
    has_ramp=True,
    default_sense_ohm=0.075,
    registers=register_names(Reg),
    shorts=(
        *SHORTS_TO_GROUND,
        (F.S2VSA, "short to supply on phase A (s2vsa)"),
        (F.S2VSB, "short to supply on phase B (s2vsb)"),
    ),
    flags=(*DRV_FLAGS, ("stealth", F.STEALTH), ("s2vsb", F.S2VSB), ("s2vsa", F.S2VSA)),
    sd_mode=F.SD_MODE,
    gstat_write_clears=True,
    uv_cp=True,
)


@dataclass(frozen=True)
class RampUnits:
    """Conversions between steps/s, steps/s^2 and the TMC5160's ramp-generator units.

    Datasheet ("real world units"): v[steps/s] = VMAX * fCLK / 2^24 and
    a[steps/s^2] = AMAX * fCLK^2 / 2^41, in the steps of the configured microstep
    resolution (one step = what one STEP pulse would move).
    """

    clock_hz: float  # fCLK: the [motors.tmc] clock_hz of the chip

    VMAX_MAX: Final = (1 << 23) - 512
    AMAX_MAX: Final = (1 << 16) - 1

    def velocity(self, steps_s: float) -> int:
        return max(0, min(self.VMAX_MAX, round(abs(steps_s) * (1 << 24) / self.clock_hz)))

    def accel(self, steps_s2: float) -> int:
        v = round(abs(steps_s2) * (1 << 41) / (self.clock_hz * self.clock_hz))
        return max(1, min(self.AMAX_MAX, v))

    def decel(self, steps_s2: float) -> int:
        """As :meth:`accel`, rounded up: the chip brakes at least as hard as planned, so a
        stop planned by the engine never overshoots its target for rounding."""
        v = math.ceil(abs(steps_s2) * (1 << 41) / (self.clock_hz * self.clock_hz) - 1e-9)
        return max(1, min(self.AMAX_MAX, v))

    def steps_s(self, vreg: int) -> float:
        return vreg * self.clock_hz / (1 << 24)

    def steps_s2(self, areg: int) -> float:
        return areg * self.clock_hz * self.clock_hz / (1 << 41)


class RampMode:
    """RAMPMODE's values."""

    POSITION: Final = 0
    VELOCITY_POS: Final = 1
    VELOCITY_NEG: Final = 2
    HOLD: Final = 3


@dataclass(frozen=True)
class RampState:
    """XACTUAL, VACTUAL (both signed) and RAMP_STAT, read in one bus session."""

    xactual: int
    vactual: int
    ramp_stat: int

    def flag(self, f: Field) -> bool:
        return bool(f.get(self.ramp_stat))

    @property
    def stopped(self) -> bool:
        return self.vactual == 0


@dataclass
class RefSwitches:
    """The TMC5160's REFL/REFR inputs: polarity (True = active low)."""

    left_active_low: bool = False
    right_active_low: bool = False


class Tmc5160(TmcDriver, RampDriver):
    """A TMC5160 whose own ramp generator moves the motor (SD_MODE low): the HAL's
    :class:`~motorctl.hal.interfaces.RampDriver` capability. ``poll_s``/``idle_poll_s``:
    how often its executor reads it (``[spidev] ramp_poll_ms``/``ramp_idle_poll_ms``);
    ``known``: as :class:`~motorctl.hal.layers.tmc.driver.TmcDriver`'s."""

    def __init__(
        self,
        name: str,
        device: SpiBus,
        settings: TmcSettings,
        switches: RefSwitches | None = None,
        *,
        poll_s: float = RampDriver.poll_s,
        idle_poll_s: float = RampDriver.idle_poll_s,
        known: Iterable[Chip] = (),
    ) -> None:
        if settings.chip is not TMC5160:
            raise ValueError("the ramp generator needs a TMC5160")
        super().__init__(name, device, settings, known)
        self.units = RampUnits(settings.clock_hz)
        self.switches = switches or RefSwitches()
        self.sw_mode = self._sw_mode_base()
        self.sg_stopped = False  # the chip stopped itself on stallGuard (set by the executor)
        self.poll_s = poll_s
        self.idle_poll_s = idle_poll_s

    def _sw_mode_base(self) -> int:
        sw = F.POL_STOP_L.put(0, int(self.switches.left_active_low))
        return F.POL_STOP_R.put(sw, int(self.switches.right_active_low))

    def _bring_up(self) -> None:
        super()._bring_up()
        if F.SD_MODE.get(self.link.read(Reg.IOIN)):
            raise TmcError(
                f"{self.device.path} ({self.name}): the TMC5160's SD_MODE pin is high, so "
                "it takes STEP/DIR and its ramp generator is off; tie SD_MODE to GND or "
                'configure the motor with mode = "step_dir"'
            )
        self.ramp_init()

    def reinit(self) -> None:
        """A reset cleared the ramp registers too (and XACTUAL: the position is lost)."""
        self.configure()
        self.ramp_init()

    def ramp_init(self) -> None:
        """Hold still where it is, with the ramp registers the datasheet requires non-zero."""
        link = self.link
        x = signed32(link.read(Reg.XACTUAL))
        link.write(Reg.RAMPMODE, RampMode.HOLD)
        link.write(Reg.VMAX, 0)
        link.write(Reg.XTARGET, x)
        link.write(Reg.VSTART, 0)
        link.write(Reg.V1, 0)  # single acceleration phase: AMAX/DMAX only
        link.write(Reg.VSTOP, VSTOP_MIN)
        link.write(Reg.TZEROWAIT, 0)
        link.write(Reg.SW_MODE, self.sw_mode)
        link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
        link.write(Reg.RAMPMODE, RampMode.POSITION)
        self.verify_ramp(x)

    def verify_ramp(self, x: int) -> None:
        mode, target, sw = self.link.read_many([Reg.RAMPMODE, Reg.XTARGET, Reg.SW_MODE])
        if (mode & 3, signed32(target), sw) != (RampMode.POSITION, x, self.sw_mode):
            raise TmcError(
                f"{self.device.path} ({self.name}): ramp registers read back wrong "
                f"(RAMPMODE={mode}, XTARGET={signed32(target)}, SW_MODE=0x{sw:x})"
            )

    def watch(self, direction: int, stall: bool = False, release: int = 0) -> None:
        """Stop switches for the next motion: the one ahead in ``direction`` (+1: REFR,
        -1: REFL, 0: none) stops the motor hard and latches XACTUAL into XLATCH on its active
        edge; ``stall``: stallGuard stops it (sg_stop); ``release`` (+1: REFR, -1: REFL, 0:
        none): that switch latches XACTUAL on its inactive edge (it stops nothing). Old
        latches and events are cleared."""
        sw = self._sw_mode_base()
        if direction > 0:
            sw = F.LATCH_R_ACTIVE.put(F.STOP_R_ENABLE.put(sw, 1), 1)
        elif direction < 0:
            sw = F.LATCH_L_ACTIVE.put(F.STOP_L_ENABLE.put(sw, 1), 1)
        if release > 0:
            sw = F.LATCH_R_INACTIVE.put(sw, 1)
        elif release < 0:
            sw = F.LATCH_L_INACTIVE.put(sw, 1)
        if stall:
            sw = F.SG_STOP.put(sw, 1)
        with self.device.session():
            self.link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
            self.link.write(Reg.SW_MODE, sw)
        self.sg_stopped = False

    def status(self) -> DriverStatus:
        """As :meth:`TmcDriver.status`; a stop by stallGuard (seen by the executor) is a stall."""
        status = super().status()
        if self.sg_stopped and not status.stall:
            return DriverStatus(status.fault, stall=True)
        return status

    def _ramps(self, acc: float, dec: float) -> None:
        a, d = self.units.accel(acc), self.units.decel(dec)
        self.link.write(Reg.AMAX, a)
        self.link.write(Reg.A1, a)
        self.link.write(Reg.DMAX, d)
        self.link.write(Reg.D1, d)  # never 0 in positioning mode, even with V1 = 0

    def move_to(self, target: int, speed: float, acc: float, dec: float) -> None:
        """Positioning mode: run a trapezoid to ``target`` (steps)."""
        with self.device.session():
            self._ramps(acc, dec)
            self.link.write(Reg.VMAX, self.units.velocity(speed))
            self.link.write(Reg.RAMPMODE, RampMode.POSITION)
            self.link.write(Reg.XTARGET, target)

    def run(self, direction: int, speed: float, acc: float) -> None:
        """Velocity mode: accelerate with ``acc`` to ``speed`` in ``direction`` (+1/-1)."""
        with self.device.session():
            self.link.write(Reg.AMAX, self.units.accel(acc))
            self.link.write(Reg.VMAX, self.units.velocity(speed))
            mode = RampMode.VELOCITY_POS if direction > 0 else RampMode.VELOCITY_NEG
            self.link.write(Reg.RAMPMODE, mode)

    def stop(self, dec: float | None) -> None:
        """Stop along ``dec`` (steps/s^2), or as hard as the chip can (``None``)."""
        with self.device.session():
            a = self.units.AMAX_MAX if dec is None else self.units.decel(dec)
            state = self.state()
            self.link.write(Reg.AMAX, a)
            self.link.write(Reg.DMAX, a)
            self.link.write(Reg.D1, a)
            self.link.write(Reg.VMAX, 0)  # velocity mode ramps to 0 with AMAX
            mode = RampMode.VELOCITY_POS if state.vactual >= 0 else RampMode.VELOCITY_NEG
            self.link.write(Reg.RAMPMODE, mode)

    def state(self) -> RampState:
        x, v, rs = self.link.read_many([Reg.XACTUAL, Reg.VACTUAL, Reg.RAMP_STAT])
        return RampState(signed32(x), F.VACTUAL.get(v), rs)

    def ramp_status(self) -> RampStatus:
        """:meth:`state` in the HAL's terms: REFL is the min side, REFR the max side."""
        st = self.state()
        v = st.vactual
        return RampStatus(
            position=st.xactual,
            velocity=self.units.steps_s(abs(v)) * (1 if v >= 0 else -1),
            active_min=st.flag(F.STATUS_STOP_L),
            active_max=st.flag(F.STATUS_STOP_R),
            stopped_min=st.flag(F.EVENT_STOP_L),
            stopped_max=st.flag(F.EVENT_STOP_R),
            latched_min=st.flag(F.STATUS_LATCH_L),
            latched_max=st.flag(F.STATUS_LATCH_R),
            stall_stopped=st.flag(F.EVENT_STOP_SG),
        )

    def latched_position(self) -> int:
        """XLATCH: XACTUAL at the reference switch's edge that :meth:`watch` armed."""
        return signed32(self.link.read(Reg.XLATCH))

    def report_stall_stop(self) -> bool:
        if self.sg_stopped:
            return False
        self.sg_stopped = True  # status() reports the stall: the driver poller hands it on
        return True

    def position(self) -> int:
        return signed32(self.link.read(Reg.XACTUAL))

    def set_position(self, x: int) -> None:
        """Declare the (standing) motor to be at ``x`` without moving it."""
        with self.device.session():
            self.link.write(Reg.RAMPMODE, RampMode.HOLD)
            self.link.write(Reg.VMAX, 0)
            self.link.write(Reg.XACTUAL, x)
            self.link.write(Reg.XTARGET, x)
            self.link.write(Reg.RAMPMODE, RampMode.POSITION)

    def home_start(self, direction: int, speed: float, acc: float, source: str) -> None:
        """Run toward the reference switch (REFR for +, REFL for -) or until stallGuard stops
        the chip; the switch's active edge stops it."""
        with self.device.session():
            self.watch(0 if source == "stall" else direction, stall=source == "stall")
            self.run(direction, speed, acc)

    def home_event(self, state: RampState, direction: int, source: str) -> bool:
        """True when the homing stop happened (the chip stopped the motor itself)."""
        if source == "stall":
            return state.flag(F.EVENT_STOP_SG)
        return state.flag(F.EVENT_STOP_R if direction > 0 else F.EVENT_STOP_L)

    def home_release(self, direction: int, speed: float, acc: float) -> None:
        """After the switch stopped homing in ``direction``: back off it at ``speed`` (the
        homing's slow speed) until it releases; its inactive edge latches XACTUAL into XLATCH
        (:meth:`home_released`). The switch on the far side stops the back-off."""
        with self.device.session():
            self.link.write(Reg.VMAX, 0)  # else disarming the stop would start it again
            self.watch(-direction, release=direction)
            self.run(-direction, speed, acc)

    def home_released(self, state: RampState, direction: int) -> bool:
        """True once the switch that homing in ``direction`` ran into has released again
        (its inactive edge latched the position): then :meth:`stop`, and once it stands,
        :meth:`home_finish`."""
        return state.flag(F.STATUS_LATCH_R if direction > 0 else F.STATUS_LATCH_L)

    def home_finish(self, source: str) -> int:
        """With the motor standing: make the reference position 0; returns where the motor
        stands then (steps past the reference).

        The reference: where the switch released (XLATCH, latched on :meth:`home_release`),
        so that position 0 is off the switch; for a stall, where it stalled. Stop switches,
        latches and sg_stop are disarmed again so that the motor can leave.
        """
        sw_inactive = F.LATCH_L_INACTIVE.mask | F.LATCH_R_INACTIVE.mask
        with self.device.session():
            self.link.write(Reg.VMAX, 0)  # else clearing the stop would start it again
            self.link.write(Reg.RAMPMODE, RampMode.HOLD)
            x, latch, sw, rs = (
                signed32(v)
                for v in self.link.read_many([Reg.XACTUAL, Reg.XLATCH, Reg.SW_MODE, Reg.RAMP_STAT])
            )
            latched = rs & (F.STATUS_LATCH_L.mask | F.STATUS_LATCH_R.mask)
            if source != "stall" and not (sw & sw_inactive and latched):
                raise TmcError(
                    f"{self.device.path} ({self.name}): homing on the reference switch ends "
                    "where it releases: back off with home_release until home_released"
                )
            ref = x if source == "stall" else latch
            self.link.write(Reg.SW_MODE, self._sw_mode_base())
            self.link.write(Reg.RAMP_STAT, RAMP_STAT_WC)
            self.set_position(x - ref)
        return x - ref
