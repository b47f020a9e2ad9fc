"""A register-level model of one dSPIN chip (L6470, L6472, L6480, powerSTEP01) for the mock
backend: fed the SPI bytes one at a time as its shift register latches them (dspin_chain.py
puts N of them on one chip select as py-spidev's ``xfer2`` drives it), it decodes commands
by the datasheet (:mod:`motorctl.hal.dspin`), holds the registers, runs the chip's own
motion profile (dspin_motion.py) over time it is handed (:meth:`DspinChip.advance`), and
drives BUSY and FLAG from its state, the SW input and the faults a test injects.

What the model does as the datasheets say (docs/dspin.md, "The chip model"):

- SPI: every byte out is the next byte of the answer being sent (GetParam, GetStatus: MSB
  first, from the byte after the command on) or 0x00; a new GetParam/GetStatus replaces an
  answer not yet sent out. A byte that is no command of this chip, a SetParam of a
  read-only register or a Get/SetParam of an address the chip has no register at is
  ignored with WRONG_CMD (CMD_ERROR on the L6480/powerSTEP01) at that byte, and the chip
  waits for a command again; a SetParam whose condition (motor stopped, bridges in HiZ)
  does not hold is ignored with NOTPERF_CMD (CMD_ERROR) after its last byte; so is Move
  (StepClock) unless the motor stands, GoTo, GoTo_DIR, GoHome, GoMark while BUSY.
- Flags: SW_EVN, the command errors, UVLO, UVLO_ADC, the thermal flags, OCD, STEP_LOSS_A/B
  latch; GetStatus answers STATUS and then clears the latched flags whose condition has
  gone; GetParam(STATUS) clears nothing. At power-up UVLO is latched (FLAG low) and the
  bridges are in HiZ.
- SW (the switch input): its closing (the pin's falling edge) latches SW_EVN; with
  CONFIG.SW_MODE = 0 (reset value) it hard-stops the motor; GoUntil does its ACT there
  (ABS_POS = 0, or ABS_POS copied to MARK) and then a SoftStop (a HardStop with SW_MODE 0);
  ReleaseSW, once the switch is open, does its ACT and a HardStop.
- Faults (:meth:`DspinChip.inject`): UVLO and thermal shutdown turn the bridges off (HiZ,
  the motor stops at once), OCD too when CONFIG.OC_SD = 1; STEP_LOSS_A/B and the thermal
  warning only raise their flags.

What is the model's own (the datasheets do not say): while the bridges are held off by a
fault (UVLO, thermal shutdown, OCD with OC_SD) a motion command is refused with
NOTPERF_CMD; ReleaseSW with the switch already open does its ACT at once and stands;
GoUntil with the switch already closed waits for the next closing (an edge, as SW_EVN);
ADC_OUT reads 0; ResetDevice does not latch UVLO (power-up does); SYNC_EN (BUSY/SYNC
as a sync output) and step-clock mode's STCK input are not modelled.

Owned by the thread that drives the mock world; not thread-safe.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from fractions import Fraction

from motorctl.hal.backends.mock.dspin_motion import Kind, Motion, Ramps
from motorctl.hal.dspin import commands, scales
from motorctl.hal.dspin.chips import POWERSTEP01_CURRENT, POWERSTEP01_VOLTAGE, Chip
from motorctl.hal.dspin.commands import Command, Decoded, Op
from motorctl.hal.dspin.registers import ABS_POS_BITS, Access, Register
from motorctl.hal.dspin.status import MotorState, ThermalState

#: the faults a test can inject, by the L6470's names (the L6480's TH_STATUS is made of
#: TH_WRN and TH_SD: warning, bridge shutdown)
FAULTS = ("UVLO", "UVLO_ADC", "TH_WRN", "TH_SD", "OCD", "STEP_LOSS_A", "STEP_LOSS_B")
#: the conditions that turn the bridges off
_SHUTDOWN = ("UVLO", "TH_SD")
_POSITIONING = (Op.GO_TO, Op.GO_TO_DIR, Op.GO_HOME, Op.GO_MARK)
_WRAP = 1 << ABS_POS_BITS


def wrap22(value: int) -> int:
    """``value`` as ABS_POS holds it: 22-bit two's complement."""
    value &= _WRAP - 1
    return value - _WRAP if value >> (ABS_POS_BITS - 1) else value


class DspinChip:
    """One chip. ``switch``: where the switch is, as a function of the motor's shaft
    position in microsteps (``shaft``: counted from power-up, never reset, unlike ABS_POS);
    without it the switch is what :meth:`set_switch` last set. ``stops``: where the
    mechanics let the shaft go when the chip drives it towards a shaft position (a hard
    stop): a step it cannot take is lost (ABS_POS counts it, the shaft stays) and, on a
    chip with stall detection, latches STEP_LOSS_A (the stall; FLAG falls)."""

    def __init__(
        self,
        chip: Chip,
        switch: Callable[[int], bool] | None = None,
        stops: Callable[[int], int] | None = None,
    ) -> None:
        self.chip = chip
        self.model = chip.model
        self._switch_fn = switch
        self._stops_fn = stops
        self.shaft = 0
        self.active: set[str] = set()  # injected conditions present now
        self.latched: set[str] = set()  # latched flags (and command errors)
        self._sw = False
        #: called when FLAG or BUSY may have changed (a fault injected, a transfer, time):
        #: the mock's FLAG and BUSY lines (dspin_world.py)
        self.listeners: list[Callable[[], None]] = []
        self.power_up()

    # state
    def power_up(self) -> None:
        """Power-up: registers at their reset values, bridges off, UVLO latched."""
        self._reset()
        self.latched = {"UVLO"}

    def _reset(self) -> None:
        if self.model == "powerSTEP01":
            self.chip = POWERSTEP01_VOLTAGE
        self.regs = {r.name: r.reset or 0 for r in self.chip.registers}
        self.motion = Motion()
        self.hiz = True
        self.step_clock = False
        self._out: deque[int] = deque()
        self._pending: Decoded | None = None
        self._args = bytearray()
        self._kind: Op | None = None  # the motion command being carried out
        self._act = 0  # its ACT (GoUntil, ReleaseSW)
        self._hiz_after_stop = False  # SoftHiZ: HiZ once stopped
        self._sw = self._switch_fn(self.shaft) if self._switch_fn else self._sw

    @property
    def abs_pos(self) -> int:
        return self.regs["ABS_POS"]

    @property
    def microsteps(self) -> int:
        return self.chip.microsteps(
            self.chip.registers["STEP_MODE"].field("STEP_SEL").get(self.regs["STEP_MODE"])
        )

    def _config(self, name: str) -> int:
        return self.chip.config.field(name).get(self.regs["CONFIG"])

    def ramps(self) -> Ramps:
        """The motion registers in full steps (what the motion engine runs on)."""
        regs = self.regs
        min_reg = self.chip.registers["MIN_SPEED"]
        lspd = "LSPD_OPT" in {f.name for f in min_reg.fields} and bool(
            min_reg.field("LSPD_OPT").get(regs["MIN_SPEED"])
        )
        return Ramps(
            acc=float(scales.ACC.value(regs["ACC"])),
            dec=float(scales.DEC.value(regs["DEC"])),
            max_speed=float(scales.MAX_SPEED.value(regs["MAX_SPEED"])),
            min_speed=float(scales.MIN_SPEED.value(regs["MIN_SPEED"] & 0xFFF)),
            microsteps=self.microsteps,
            lspd_opt=lspd,
        )

    @property
    def switch_closed(self) -> bool:
        return self._sw

    @property
    def busy(self) -> bool:
        """BUSY (the pin is low while this is True)."""
        return self.motion.busy

    @property
    def flag(self) -> bool:
        """FLAG (the pin is low while this is True): an alarm ALARM_EN enables is on."""
        enabled = self.regs["ALARM_EN"]
        return any(enabled >> bit & 1 for bit in self._alarms())

    def _alarms(self) -> list[int]:
        on = self.active | self.latched
        cmd = bool(on & {"WRONG_CMD", "NOTPERF_CMD"})
        if self.chip.status.by_name.get("TH_STATUS") is None:
            names = ["OCD", "TH_SD", "TH_WRN", "UVLO", "STEP_LOSS_A", "STEP_LOSS_B", "SW_EVN"]
            bits = [i for i, n in enumerate(names) if n in on and self.chip.alarms[i]]
        else:
            stall = bool(on & {"STEP_LOSS_A", "STEP_LOSS_B"})
            flags = [
                "OCD" in on,
                "TH_SD" in on,
                "TH_WRN" in on,
                "UVLO" in on,
                "UVLO_ADC" in on,
                stall,
                "SW_EVN" in on,
            ]
            bits = [i for i, f in enumerate(flags) if f]
        return [*bits, 7] if cmd else bits

    def status_word(self) -> int:
        """STATUS as the chip would answer it now."""
        layout = self.chip.status
        word = layout.idle_word
        on = self.active | self.latched

        def put(name: str, level: int) -> None:
            nonlocal word
            flag = layout.by_name.get(name)
            if flag is None:
                return
            raw = level ^ 1 if flag.active_low and flag.width == 1 else level
            word = (word & ~flag.mask) | (raw << flag.bit)

        put("HiZ", int(self.hiz))
        put("BUSY", int(self.busy))
        put("SW_F", int(self._sw))
        put("DIR", int(self.motion.direction > 0))
        put("MOT_STATUS", int(self.motion.state if self.motion.speed else MotorState.STOPPED))
        put("SCK_MOD", int(self.step_clock))
        put("STCK_MOD", int(self.step_clock))
        for name in ("SW_EVN", "NOTPERF_CMD", "WRONG_CMD", "UVLO", "UVLO_ADC", "OCD"):
            put(name, int(name in on))
        put("STEP_LOSS_A", int("STEP_LOSS_A" in on))
        put("STEP_LOSS_B", int("STEP_LOSS_B" in on))
        put("TH_WRN", int("TH_WRN" in on))
        put("TH_SD", int("TH_SD" in on))
        put("CMD_ERROR", int(bool(on & {"WRONG_CMD", "NOTPERF_CMD"})))
        thermal = ThermalState.NORMAL
        if "TH_SD" in on:
            thermal = ThermalState.BRIDGE_SHUTDOWN
        elif "TH_WRN" in on:
            thermal = ThermalState.WARNING
        put("TH_STATUS", int(thermal))
        return word

    # SPI, as the chain hands it the bytes
    def shift_out(self) -> int:
        """The byte this chip shifts out in the next transfer (loaded as CS falls)."""
        return self._out.popleft() if self._out else 0x00

    def receive(self, byte: int) -> None:
        """A byte latched in as CS rises."""
        if self._pending is not None:
            self._args.append(byte)
            if len(self._args) == self._pending.argument:
                pending, self._pending = self._pending, None
                self._execute(pending.command(bytes(self._args)))
            return
        decoded = commands.decode(self.chip, byte)
        if decoded.wrong:
            self.latched.add("WRONG_CMD")
            return
        if decoded.argument:
            self._pending = decoded
            self._args = bytearray()
            return
        self._execute(decoded.command())

    def _refuse(self) -> None:
        self.latched.add("NOTPERF_CMD")

    def _execute(self, cmd: Command) -> None:
        op = cmd.op
        if op is Op.NOP:
            return
        if op is Op.SET_PARAM:
            assert cmd.register is not None
            self._set_param(cmd.register, cmd.value)
        elif op is Op.GET_PARAM:
            assert cmd.register is not None
            self._answer(self._read(cmd.register), cmd.register.nbytes)
        elif op is Op.GET_STATUS:
            self._answer(self.status_word(), 2)
            self.latched -= {n for n in self.latched if n not in self.active}
        elif op is Op.RESET_DEVICE:
            self._reset()
        elif op is Op.RESET_POS:
            self.regs["ABS_POS"] = 0
        elif op in (Op.SOFT_STOP, Op.HARD_STOP, Op.SOFT_HIZ, Op.HARD_HIZ):
            self._stop(op)
        else:
            self._motion(cmd)

    def _answer(self, word: int, nbytes: int) -> None:
        self._out = deque(word.to_bytes(nbytes, "big"))

    def _read(self, reg: Register) -> int:
        if reg.name == "STATUS":
            return self.status_word()
        if reg.name == "SPEED":
            return min(scales.SPEED.floor(Fraction(self.motion.speed)), scales.SPEED.hi)
        return reg.word(self.regs[reg.name]) if reg.signed else self.regs[reg.name]

    def _set_param(self, reg: Register, value: int) -> None:
        stopped = self.motion.stopped
        if (reg.access is Access.STOPPED and not stopped) or (
            reg.access is Access.HIZ and not self.hiz
        ):
            self._refuse()
            return
        self.regs[reg.name] = value
        if reg.name == "STEP_MODE" and self.model == "powerSTEP01":
            current = reg.field("CM_VM").get(value)
            self.chip = POWERSTEP01_CURRENT if current else POWERSTEP01_VOLTAGE

    def _stop(self, op: Op) -> None:
        if op in (Op.HARD_STOP, Op.HARD_HIZ) or self.motion.stopped:
            self.motion.halt()
        else:
            self.motion.soft_stop()
            self._hiz_after_stop = op is Op.SOFT_HIZ
        if op is Op.HARD_HIZ or (op is Op.SOFT_HIZ and self.motion.stopped):
            self.hiz = True
        elif op in (Op.SOFT_STOP, Op.HARD_STOP):
            self.hiz = False  # a stop command turns the bridges on, no motion
        self.step_clock = False

    def _bridges_held_off(self) -> bool:
        return bool(self.active & set(_SHUTDOWN)) or (
            "OCD" in self.active and bool(self._config("OC_SD"))
        )

    def _motion(self, cmd: Command) -> None:
        op = cmd.op
        if self._bridges_held_off():
            self._refuse()
            return
        if (op in (Op.MOVE, Op.STEP_CLOCK) and not self.motion.stopped) or (
            op in _POSITIONING and self.motion.busy
        ):
            self._refuse()
            return
        ramps = self.ramps()
        direction = 1 if cmd.dir else -1
        self.hiz = False
        self.step_clock = False
        self._act = cmd.act
        self._kind = op
        self._hiz_after_stop = False
        if op in (Op.RUN, Op.GO_UNTIL):
            until = op is Op.GO_UNTIL
            self.motion.run(direction, float(scales.SPEED.value(cmd.value)), ramps, until)
        elif op is Op.MOVE:
            self.motion.position(direction, cmd.value, ramps)
        elif op in _POSITIONING:
            self._go_to(op, cmd, ramps)
        elif op is Op.RELEASE_SW:
            if not self._sw:
                self._do_act(cmd.act)
                self.motion.halt()
            else:
                self.motion.release(direction, ramps)
        elif op is Op.STEP_CLOCK:
            self.step_clock = True
            self.motion.direction = direction

    def _go_to(self, op: Op, cmd: Command, ramps: Ramps) -> None:
        target = {Op.GO_HOME: 0, Op.GO_MARK: self.regs["MARK"]}.get(op, cmd.value)
        ahead = (target - self.abs_pos) % _WRAP  # microsteps forward to the target
        if op is Op.GO_TO_DIR:
            direction = 1 if cmd.dir else -1
        else:  # the shortest way round
            direction = 1 if ahead < _WRAP // 2 else -1
        distance = ahead if direction > 0 else (_WRAP - ahead) % _WRAP
        self.motion.position(direction, distance, ramps)

    def _do_act(self, act: int) -> None:
        if act == commands.COPY_TO_MARK:
            self.regs["MARK"] = self.abs_pos
        else:
            self.regs["ABS_POS"] = 0

    # the SW input and faults
    def set_switch(self, closed: bool) -> None:
        """Set the SW input (True: closed, the pin pulled low)."""
        if closed != self._sw:
            self._sw = closed
            self._switch_edge(closed)

    def _switch_edge(self, closed: bool) -> None:
        kind = self._kind
        if closed:
            self.latched.add("SW_EVN")
            if kind is Op.GO_UNTIL and self.motion.kind is Kind.RUN:
                self._do_act(self._act)
                self._kind = None
                if self._config("SW_MODE"):
                    self.motion.soft_stop()
                else:
                    self.motion.halt()
            elif not self._config("SW_MODE"):
                self.motion.halt()  # the hard stop interrupt
        elif kind is Op.RELEASE_SW and self.motion.kind is Kind.RELEASE:
            self._do_act(self._act)
            self._kind = None
            self.motion.halt()

    def inject(self, fault: str, present: bool = True) -> None:
        """Make ``fault`` (one of FAULTS) present or gone; present, it latches."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}: one of {', '.join(FAULTS)}")
        if not present:
            self.active.discard(fault)
            return
        self.active.add(fault)
        self.latched.add(fault)
        if self._bridges_held_off():
            self.motion.halt()
            self.hiz = True
        self.changed()

    def changed(self) -> None:
        """Tell the listeners that FLAG or BUSY may have changed."""
        for listener in self.listeners:
            listener()

    def _rotor(self, shaft: int) -> int:
        """Where the shaft gets to when driven to ``shaft``: a hard stop holds it; pushed
        on while it stands there, the chip sees the stall (STEP_LOSS latched while it
        lasts). Reaching the stop within a sub-step is no stall yet: a switch there (SW
        closes on the same position) stops the chip first, as it would between two
        microsteps."""
        got = shaft if self._stops_fn is None else self._stops_fn(shaft)
        pushed = got != shaft and got == self.shaft
        if pushed and self.chip.status.by_name.get("STEP_LOSS_A") is not None:
            self.latched.add("STEP_LOSS_A")
        return got

    # time
    def _go(self, steps: int) -> None:
        """The chip counts the microsteps it drives; the shaft follows them unless a hard
        stop holds it (:meth:`_rotor`)."""
        self.regs["ABS_POS"] = wrap22(self.abs_pos + steps)
        self.shaft = self._rotor(self.shaft + steps)

    def _travel(self, moved: int) -> None:
        """The shaft on by ``moved`` microsteps, the switch watched at each one: the chip
        samples SW all the time, so an edge acts at the microstep where the switch changed
        (a hard stop there), not at the end of the sub-step that crossed it."""
        if self._switch_fn is None or moved == 0:
            self._go(moved)
            return
        done, switch = 0, self._switch_fn
        while done != moved:
            if switch(self.shaft + moved - done) == self._sw:
                self._go(moved - done)  # no edge before the end (one edge per sub-step)
                return
            lo, hi = 0, moved - done  # the switch is as now at lo, changed at hi
            while abs(hi - lo) > 1:
                mid = (lo + hi) // 2 if hi > 0 else -((-lo - hi) // 2)
                if switch(self.shaft + mid) == self._sw:
                    lo = mid
                else:
                    hi = mid
            self._go(hi)
            done += hi
            idle = self.motion.idle
            self.set_switch(not self._sw)
            if self.motion.idle and not idle:
                return  # the edge stopped the motor there

    def advance(self, dt: float) -> None:
        """Let ``dt`` seconds pass: the motor moves, the switch is watched. A chip at rest
        stays as it is (its ramp registers are not even read)."""
        if self.motion.idle:
            return
        ramps = self.ramps()
        left = dt
        while left > 1e-12:
            if self.motion.idle:
                break
            h = min(left, 0.0005)
            left -= h
            self._travel(self.motion.advance(h, ramps))
            if self.motion.idle and self._hiz_after_stop:
                self.hiz = True
                self._hiz_after_stop = False
