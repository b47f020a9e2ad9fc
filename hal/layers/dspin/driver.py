"""The dSPIN chips of a motorctl machine: a chain on its SPI bus (:class:`Chain`) and each
chip's driver (:class:`DspinDriver`): its start-up, its STATUS as the HAL's driver poller
reads it, and the HAL's :class:`~motorctl.hal.interfaces.RampDriver` capability (the chip
runs its own ramps: GoTo_DIR, Run, GoUntil, ReleaseSW, SoftStop, HardStop).

**GetStatus clears the latched flags** (UVLO, thermal, OCD, STEP_LOSS, SW_EVN, the command
errors), so every GetStatus of a chip goes through :meth:`DspinDriver.took`, which keeps
what it read until its reader takes it: the faults until the driver poller's next reading
reports them (E4), SW_EVN until the ramp's next read (an end stop). The poller reads every
chip of a chain in one exchange (:meth:`Chain.poll`); the executor's reads use GetParam,
which clears nothing, except the one a motion starts from, which clears the switch's old
event (a GetStatus, its faults kept for the poller): :meth:`DspinDriver.command_status`,
or :meth:`DspinDriver.watch` where none came before it.

**One read per command**: a motion command costs one GetStatus and one ABS_POS (SPEED too
where the motor moves) before the chip's commands: :meth:`DspinDriver.command_status` (the
executor's ``committed()``, which the engine plans from) reads them, and the
:meth:`~DspinDriver.watch` and :meth:`~DspinDriver.move_to` or :meth:`~DspinDriver.run`
that follow at once go by what it found (``_Seen``) instead of reading again: what STATUS
says of a motor at rest stays true until a command reaches the chip (it neither starts nor
raises BUSY on its own), and of a moving one it is as fresh as a read in between would be
(a BUSY found low may have gone high since: the GoTo then becomes a SoftStop, as for a
read just before); only GoTo_DIR's direction towards a target reads ABS_POS again where the
motor moves. Any other call, and any command sent, forgets it.

**Stall homing** (``homing.source = "stall"``): :meth:`DspinDriver.watch` with ``stall``
arms the chip's stall detection for the motion: STEP_LOSS_A/B (STALL_TH) is then the
motor's stall, not a fault: the ramp's read that finds it stops the chip at once
(HardStop: the chip runs on after a stall) and the driver reports a stall
(``DriverStatus.stall``) to the driver poller, which hands it to the motion engine (it ends
the homing's run there and zeroes, docs/protocol.md's homing rule); a GetStatus that finds
it first (the poller's, at once with FLAG wired) reports it the same way.

**A rotary axis** (``DspinSpec.rotary``) has no ends: a Run goes on past ABS_POS's 22
bits, which the chip wraps (2,097,151 + 1 = -2,097,152), and the driver counts on: each
ABS_POS read is taken as the position nearest the one read before (``convert.unwrap``), so
the executor sees positions without end, as a STEP/DIR motor's step count, and motion's
rotary rule (position modulo ``steps_per_rev``) holds across the wrap; a GoTo_DIR goes to
the target wrapped to 22 bits (``convert.check_turn``). This is unambiguous while the motor
moves less than half the counter's span (2,097,152 microsteps) between two reads: the
executor reads a moving motor every ``ramp_poll_ms`` (at most 1 s) and a motor goes at most
``max_speed`` (at most 200,000 step/s), so at most 200,000 microsteps a period, a tenth of
that (tests/hal/layers/dspin/test_driver_rotary.py checks the config's bounds say so). A
linear axis keeps ABS_POS's range: a Run stops at its end (``_keep_in_range``).

Units: positions are ABS_POS (microsteps, one protocol step each), speeds step/s and
ramps step/s^2 of the protocol, converted to the registers by ``convert.py`` (clamped,
never refused; the clamps are counted in ``clamped``).

Threads: :func:`start_chain` runs on the thread that opens the hardware. Afterwards two
threads talk to a chain: the driver poller (``Chain.poll``) and the planner (the ramp
calls, with the engine's lock held); each exchange holds the bus's lock (hal/spi.py), and a
driver's kept flags are behind its own lock. :meth:`DspinDriver.status` and ``stats`` read
snapshots without I/O, from any thread.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from motorctl.hal.dspin import scales
from motorctl.hal.dspin.chips import Chip
from motorctl.hal.dspin.commands import (
    COPY_TO_MARK,
    FORWARD,
    REVERSE,
    Command,
    Op,
    get_param,
    go_to_dir,
    set_param,
    simple,
)
from motorctl.hal.dspin.spec import DspinSpec
from motorctl.hal.dspin.status import MotorState, Status
from motorctl.hal.interfaces import (
    DriverStatus,
    EdgeInputs,
    HalError,
    RampDriver,
    RampStatus,
    StepperDriver,
)
from motorctl.hal.layers.dspin import chain as framing
from motorctl.hal.layers.dspin import convert, program
from motorctl.hal.poller import Alert
from motorctl.hal.spi import SpiBus, SpiError

log = logging.getLogger("motorctl.dspin")

#: ACT of GoUntil and ReleaseSW: ABS_POS copied to MARK (the position stays continuous;
#: the motor's zero is set where MARK says, docs/protocol.md's homing rule)
MARK = COPY_TO_MARK
#: the flags that say the chip refused a command
_REFUSED = ("WRONG_CMD", "NOTPERF_CMD", "CMD_ERROR")
#: the flags of the chip's stall detection (STALL_TH)
STALL = frozenset({"STEP_LOSS_A", "STEP_LOSS_B"})
#: ALARM_EN written at start: every alarm but SW_EVN (homing closes the switch on purpose)
ALARMS_BUT_SWITCH = 0xFF & ~(1 << 6)
#: with BUSY wired, a motor at rest is read over SPI once in this many ramp reads (the
#: others answer from the last read while BUSY stays high): a switch closed by hand at rest
#: shows within this many idle periods
REST_READ_EVERY = 20


class DspinError(HalError):
    """A dSPIN chip is not what the config says, or refused its set-up; the message names
    the chip, its chain and the fix."""


class Chain:
    """The chips on one chip select: ``length`` of them on ``bus``."""

    def __init__(self, bus: SpiBus, length: int) -> None:
        self.bus = bus
        self.length = length
        self.drivers: list[DspinDriver] = []

    def exchange(self, commands: Mapping[int, Command]) -> dict[int, int]:
        """Send ``commands`` (chip -> command) together; each answering chip's value."""
        ex = framing.exchange(self.length, commands)
        return ex.values(self.bus.xfer_many(ex.transfers))

    def send(self, chip: int, commands: Sequence[Command]) -> None:
        """``commands`` for chip ``chip``, in order, in one sequence of transfers that no
        other exchange on the bus comes between (none of them answers)."""
        data = b"".join(c.encode() for c in commands)
        self.bus.xfer_many(framing.frame(self.length, {chip: data}))

    def poll(self) -> list[tuple[StepperDriver, DriverStatus]]:
        """The driver poller's read: one GetStatus of every chip in one exchange, its news
        kept before anyone else reads a chip (the bus held throughout: a motion's
        :meth:`DspinDriver.watch` comes before or after, never between)."""
        with self.bus.session():
            try:
                words = self.exchange({d.position: simple(Op.GET_STATUS) for d in self.drivers})
            except SpiError as exc:
                return [(d, d.failed(exc)) for d in self.drivers]
            return [(d, d.took(Status(d.chip.status, words[d.position]))) for d in self.drivers]


@dataclass(frozen=True)
class _Seen:
    """The chip as the read a command builds on found it: its STATUS, and ``position``,
    ABS_POS read after that STATUS (None: not read); ``cleared``: the STATUS came from a
    GetStatus (the old motion's latched events gone from the chip)."""

    status: Status
    position: int | None = None
    cleared: bool = False

    @property
    def standing(self) -> bool:
        return self.status.motor is MotorState.STOPPED


@dataclass
class _Kept:
    """What a GetStatus read that its readers have not taken yet."""

    faults: set[str] = field(default_factory=set)  # the flags' names
    spi: str | None = None  # a failed read
    switch_event: bool = False
    stall: bool = False  # STEP_LOSS while stall homing armed the detection


class DspinDriver(StepperDriver, RampDriver):
    """One chip of a chain: the motor's driver and its ramp."""

    def __init__(self, name: str, spec: DspinSpec, chain: Chain, poll_s: float, idle_s: float):
        self.name = name
        self.spec = spec
        self.chip: Chip = spec.model
        self.position = spec.position
        self.chain = chain
        self.microsteps = spec.steps_per_full
        self.poll_s = poll_s
        self.idle_poll_s = idle_s
        self._lock = threading.Lock()
        self._kept = _Kept()
        self._status = DriverStatus()
        self._watch = 0  # the switch side armed to stop the motion (+1, -1, 0)
        self._release = 0  # the side whose release ends it
        self._until = False  # the motion is a GoUntil: MARK latches the switch's edge
        self._settled = False  # the chip ended the motion short of its target on purpose
        self._limit: int | None = None  # a ReleaseSW's farthest position
        self._stall = False  # STEP_LOSS is the motion's stall (stall homing), not a fault
        self._stall_stopped = False  # a ramp read found it and stopped the chip
        self._stall_told = False  # the executor saw it (report_stall_stop): a stall
        self._run = 0  # a linear axis's Run (or GoUntil), +1/-1: watched for ABS_POS's end
        self._run_dec = 0.0  # its DEC register, step/s^2
        #: a rotary axis: the position the last ABS_POS read stood for (counted on past
        #: ABS_POS's 22 bits, ``convert.unwrap``); None before the first read
        self._at: int | None = None
        self.polls = 0
        self.spi_errors = 0
        self.clamped = 0
        self.fault_counts: dict[str, int] = {}
        self.warning_counts: dict[str, int] = {}
        self.last_status: Status | None = None
        #: the chip's BUSY output as an edge input (line 0), where wired
        self.busy_line: EdgeInputs | None = None
        self._rest: RampStatus | None = None  # the last read: standing, BUSY high
        self._rest_reads = 0  # answered from it since
        self.busy_answers = 0  # ramp reads answered from BUSY, without SPI
        self._seen: _Seen | None = None  # the read the next command builds on (_Seen)
        #: the chip's FLAG line as the driver poller's alert, where wired
        self.flag_alert: Alert | None = None

    # -- the bus ---------------------------------------------------------------------------
    def _get(self, register: str) -> int:
        reg = self.chip.registers[register]
        return self.chain.exchange({self.position: get_param(reg)})[self.position]

    def _send(self, *commands: Command) -> None:
        self._seen = None  # the chip is no longer what the last read found
        self.chain.send(self.position, commands)

    def _set(self, values: Mapping[str, int]) -> list[Command]:
        return [set_param(self.chip.registers[n], v) for n, v in values.items()]

    def _position(self, value: int) -> int:
        """The position an ABS_POS read of ``value`` stands for: the value itself on a
        linear axis; on a rotary one, counted on past the wrap from the read before."""
        if not self.spec.rotary:
            return value
        at = self._at
        self._at = value if at is None else convert.unwrap(value, at)
        return self._at

    # -- start-up --------------------------------------------------------------------------
    def start(self) -> None:
        """Check the chip and set it up, bridges in HiZ: the latched power-up flags read and
        cleared, CONFIG compared with the model's reset value, then STEP_MODE, CONFIG, the
        configured registers and ALARM_EN written and read back."""
        where = f"{self.name}: the {self.chip.name} at position {self.position} of the chain "
        where += f"on {self.chain.bus.path}"
        word = self.chain.exchange({self.position: simple(Op.GET_STATUS)})[self.position]
        config = self._get("CONFIG")
        if config != self.chip.config.reset:
            raise DspinError(
                f"{where} reads CONFIG 0x{config:04X}, not the {self.chip.name}'s 0x"
                f"{self.chip.config.reset:04X} (STATUS 0x{word:04X}): check [motors.dspin] "
                "driver and position (position 0 is the chip at MOSI) and the chain's wiring"
            )
        wanted = {
            "STEP_MODE": self.chip.step_mode(self.microsteps),
            "CONFIG": self.chip.config.reset or 0,  # SW_MODE 0: the switch hard-stops
            **dict(self.spec.registers),
            "ALARM_EN": ALARMS_BUT_SWITCH,
        }
        self._send(simple(Op.HARD_HIZ), *self._set(wanted))
        for name, value in wanted.items():
            got = self._get(name)
            if got != value:
                raise DspinError(
                    f"{where}: {name} reads 0x{got:X} after 0x{value:X} was written; check "
                    "the chain's wiring (SDO to the next SDI) and its supply"
                )
        # the power-up UVLO (and whatever the set-up latched) is gone with this read
        self.chain.exchange({self.position: simple(Op.GET_STATUS)})

    def close(self) -> None:
        """Leave the bridges off (HiZ) where so configured, the motor stopped."""
        try:
            self._send(simple(Op.HARD_HIZ if self.spec.hiz_at_exit else Op.HARD_STOP))
        except SpiError as exc:
            log.error("%s: could not stop the chip at exit: %s", self.name, exc)

    # -- the status (the driver poller) ---------------------------------------------------
    def took(self, st: Status) -> DriverStatus:
        """A GetStatus's word: keep its latched news for their readers; the driver
        poller's reading (the faults kept since its last one)."""
        self.polls += 1
        self.last_status = st
        self._keep(st)
        return self._publish()

    def _keep(self, st: Status) -> None:
        for w in st.warnings:
            self.warning_counts[w] = self.warning_counts.get(w, 0) + 1
            log.warning("%s: %s", self.name, w)
        faults = {*st.faults, *st.command_errors}
        stalled = self._stall and bool(faults & STALL)
        if self._stall:  # stall homing: the stall it looks for
            faults -= STALL
        with self._lock:
            self._kept.faults |= faults
            self._kept.switch_event |= st.switch_event
            self._kept.stall |= stalled

    def failed(self, exc: BaseException) -> DriverStatus:
        self.spi_errors += 1
        with self._lock:
            self._kept.spi = f"SPI: {exc}"
        return self._publish()

    def _publish(self) -> DriverStatus:
        """The faults kept since the last reading, now this reading's: the chip latches a
        fault until a GetStatus finds it gone, so each one is reported once at least."""
        with self._lock:
            names, spi = sorted(self._kept.faults), self._kept.spi
            stall = self._kept.stall or self._stall_told
            self._kept.faults, self._kept.spi, self._kept.stall = set(), None, False
        for name in names:
            self.fault_counts[name] = self.fault_counts.get(name, 0) + 1
        said = [f"{n} (the chip refused a command)" if n in _REFUSED else n for n in names]
        if spi is not None:
            said.append(spi)
        fault = f"{self.chip.name}: {', '.join(said)}" if said else None
        self._status = DriverStatus(fault=fault, stall=stall)
        return self._status

    def refresh(self) -> DriverStatus:
        return self._status  # the chain's poll reads every chip at once (Chain.poll)

    def status(self) -> DriverStatus:
        """The last reading's verdict (no I/O, takes nothing)."""
        return self._status

    def stats(self) -> dict[str, object]:
        return {
            "chip": self.chip.name,
            "device": self.chain.bus.path,
            "chain_position": self.position,
            "polls": self.polls,
            "spi_errors": self.spi_errors,
            "clamped": self.clamped,
            "fault_counts": dict(self.fault_counts),
            "warning_counts": dict(self.warning_counts),
            "status": None if self.last_status is None else str(self.last_status),
            "flag_line": self.spec.flag or None,
            "busy_line": self.spec.busy or None,
            "busy_answers": self.busy_answers,
            "flag_alerts": None if self.flag_alert is None else self.flag_alert.falls,
        }

    # -- the ramp (RampDriver) -------------------------------------------------------------
    def _read(self) -> tuple[int, int, Status]:
        """ABS_POS, SPEED and STATUS (GetParam: clears nothing), one exchange each, STATUS
        first: a motor it finds standing stands at the ABS_POS read after it (read first, the
        position could be from before a stop that STATUS then shows), and its SPEED is 0,
        not read (as :meth:`command_status`): a standing chip, the read after a stop
        included, costs GetParam STATUS and ABS_POS, 7 transfers, not 11."""
        st = Status(self.chip.status, self._get("STATUS"))
        pos = self._position(self._get("ABS_POS"))
        speed = 0 if st.motor is MotorState.STOPPED else self._get("SPEED")
        return pos, speed, st

    def _busy(self) -> bool:
        """BUSY's level on its line (the line read, no SPI); True without a line."""
        line = self.busy_line
        if line is None:
            return True
        try:
            line.read_edges()
            return line.level(0)
        except HalError as exc:
            raise DspinError(f"{self.name}: the BUSY line: {exc}") from exc

    def ramp_status(self) -> RampStatus:
        """One read of the ramp: ABS_POS, SPEED and STATUS (GetParam). With BUSY wired, a
        motor that stood at the last read and whose BUSY is still high (no command since)
        is answered from that read, without SPI (one read in ``REST_READ_EVERY``)."""
        self._seen = None
        rest = self._rest
        if rest is not None and self._rest_reads < REST_READ_EVERY and not self._busy():
            self._rest_reads += 1
            self.busy_answers += 1
            return rest
        self._rest = None
        try:
            pos, speed, st = self._read()
        except SpiError as exc:
            raise DspinError(f"{self.name}: {exc}") from exc
        out = self._ramp(pos, speed, st)
        standing = st.motor is MotorState.STOPPED and not st.busy and self._limit is None
        if self.busy_line is not None and standing and not self._busy():
            self._rest, self._rest_reads = out, 0
        return out

    def _ramp(self, pos: int, speed: int, st: Status) -> RampStatus:
        with self._lock:
            event = self._kept.switch_event or st.switch_event
        standing = st.motor is MotorState.STOPPED
        # STATUS, read first, says it moves: then it is not at rest, even where SPEED, read
        # after it, is 0 (it stopped in between, maybe on a switch whose event STATUS did not
        # show yet): the next read decides, or a move would end without its end stop
        magnitude = max(convert.speed_of(speed, self.microsteps), convert.speed_of(1, 1))
        velocity = magnitude * (1 if st.forward else -1)
        if not standing:
            self._bound(pos, abs(velocity), st)
        side = {"min": -1, "max": 1}.get(self.spec.switch, 0)
        stopped = bool(side and self._watch == side and event and standing)
        released = bool(side and self._release == side and not st.switch_closed and standing)
        latched = (stopped and self._until) or released
        return RampStatus(
            position=pos,
            velocity=0.0 if standing else velocity,
            active_min=side < 0 and st.switch_closed,
            active_max=side > 0 and st.switch_closed,
            stopped_min=side < 0 and stopped,
            stopped_max=side > 0 and stopped,
            latched_min=side < 0 and latched,
            latched_max=side > 0 and latched,
            settled=self._settled and standing,
            stall_stopped=self._stall_stopped,
        )

    def _bound(self, pos: int, speed: float, st: Status) -> None:
        """A moving chip that the driver stops itself: on a stall that stall homing armed
        (the chip runs on after one), at the end of a ReleaseSW that found no edge, and at
        ABS_POS's ends."""
        if self._stall and STALL & {*st.faults}:
            self._send(simple(Op.HARD_STOP))
            self._stall_stopped = True
        if self._limit is not None and st.switch_closed:
            beyond = pos >= self._limit if self._release < 0 else pos <= self._limit
            if beyond:  # ReleaseSW ran its whole way: the switch never opened
                self._send(simple(Op.HARD_STOP))
                self._settled, self._limit = True, None
        if self._run:
            self._keep_in_range(pos, speed, st.busy)

    def _keep_in_range(self, pos: int, speed: float, busy: bool) -> None:
        """A linear axis's Run stops at the end of ABS_POS's range as at a soft limit
        (docs/dspin.md, "Values the chip cannot take"): past it the counter would wrap.
        Within two polls of where braking with DEC must start, a GoTo_DIR to the end (the
        chip takes it once the Run has reached its speed and released BUSY: it brakes to
        stand exactly there), or while the chip still ramps, a SoftStop short of it; either
        ends the run as settled."""
        end = convert.ABS_POS_MAX if self._run > 0 else convert.ABS_POS_MIN
        braking = speed * speed / (2 * self._run_dec) if self._run_dec > 0 else 0.0
        if abs(end - pos) > braking + speed * 2 * self.poll_s + 1:
            return
        forward = FORWARD if self._run > 0 else REVERSE
        self._send(simple(Op.SOFT_STOP) if busy else go_to_dir(forward, end))
        self._run, self._settled = 0, True
        log.info("%s: a run stops at the end of ABS_POS's range, %d", self.name, end)

    def command_status(self) -> RampStatus:
        """The read a command builds on (the executor's ``committed()``; :meth:`watch` and
        the command follow at once): GetStatus, whose clearing of the latched flags is the
        one :meth:`watch` needs (its news kept: the faults for the poller, SW_EVN for the
        ramp's next read), then ABS_POS, and SPEED only where STATUS finds the motor moving
        (standing, its speed is 0); STATUS first, so a motor it finds standing stands at
        the ABS_POS read after it. The bus is held throughout: no poll comes between."""
        self._seen = self._rest = None
        try:
            with self.chain.bus.session():
                st = self._take_status()
                pos = self._position(self._get("ABS_POS"))
                speed = 0 if st.motor is MotorState.STOPPED else self._get("SPEED")
        except SpiError as exc:
            raise DspinError(f"{self.name}: {exc}") from exc
        self._seen = _Seen(st, pos, cleared=True)
        return self._ramp(pos, speed, st)  # a command it sends forgets _seen

    def _take_status(self) -> Status:
        """A GetStatus (it clears the chip's latches), its news kept for their readers (the
        faults for the poller, SW_EVN for the ramp's next read)."""
        word = self.chain.exchange({self.position: simple(Op.GET_STATUS)})[self.position]
        st = Status(self.chip.status, word)
        self._keep(st)
        return st

    def latched_position(self) -> int:
        """MARK (where the switch's edge was, moments ago): on a rotary axis the position
        nearest the last read that it stands for."""
        self._seen = None
        mark = self._get("MARK")
        if not self.spec.rotary or self._at is None:  # linear, or no ABS_POS read yet
            return mark
        return convert.unwrap(mark, self._at)

    def watch(self, direction: int, stall: bool = False, release: int = 0) -> None:
        """The stops of the next motion armed, the last motion's switch event and stall
        gone: the chip's latches cleared by a GetStatus, :meth:`command_status`'s where it
        came just before, else one read here (its faults stay for the poller)."""
        seen, self._seen = self._seen, None
        with self.chain.bus.session():  # no poll between the read and the clearing
            if seen is None or not seen.cleared:
                seen = _Seen(self._take_status(), cleared=True)
            with self._lock:  # the last motion's switch and stall are gone with it
                self._kept.switch_event = self._kept.stall = False
            self._stall, self._stall_stopped, self._stall_told = stall, False, False
        self._watch, self._release = direction, release
        self._until = self._settled = False
        self._limit = None
        self._rest = None
        self._run = 0
        self._seen = seen  # what the command that follows goes by

    def _take(self) -> _Seen:
        """What the read before this command found (forgotten here), or a read of STATUS
        now (GetParam: clears nothing) where none came before."""
        seen, self._seen = self._seen, None
        if seen is None:
            seen = _Seen(Status(self.chip.status, self._get("STATUS")))
        return seen

    def _do(self, p: program.Program) -> None:
        self.clamped += len(p.clamped)
        self._rest = None  # the chip moves again: read it until it stands
        self._send(*p.commands)

    def move_to(self, target: int, speed: float, acc: float, dec: float) -> None:
        seen = self._take()
        if self._release:  # homing's back-off: ReleaseSW at MIN_SPEED to where it opens
            self._limit = target
            self._do(program.release(self.chip, self.microsteps, self._release > 0, speed, MARK))
            return
        standing = seen.standing
        if seen.status.busy and not standing:  # GoTo while BUSY is refused: a stop along DEC
            self._settled = True
            self._do(program.stop(hard=False))
            return
        # GoTo_DIR's direction: from where a standing motor stands, a moving one is now
        if standing and seen.position is not None:
            pos = seen.position
        else:
            pos = self._position(self._get("ABS_POS"))
        try:
            p = program.move_to(
                self.chip,
                self.microsteps,
                pos,
                target,
                speed,
                acc,
                dec,
                at_rest=standing,
                rotary=self.spec.rotary,
            )
        except convert.OutOfRange as exc:
            raise DspinError(f"{self.name}: {exc}") from exc
        self._do(p)

    def run(self, direction: int, speed: float, acc: float) -> None:
        standing = self._take().standing
        # a linear axis's run is watched for ABS_POS's end with the DEC the chip will have
        # (written at rest only); a rotary axis's runs on past it (the counter wraps)
        if self.spec.rotary:
            self._run = 0
        elif standing:
            self._run, self._run_dec = direction, convert.ramp(acc, self.microsteps).value
        else:
            dec = float(scales.ACC.value(self._get("DEC")) * self.microsteps)
            self._run, self._run_dec = direction, dec
        up = direction > 0
        side = {"min": -1, "max": 1}.get(self.spec.switch, 0)
        if side and self._watch == side == direction:  # to the switch: MARK at its edge
            self._until = True
            self._do(program.home(self.chip, self.microsteps, up, speed, acc, acc, standing, MARK))
            return
        self._do(program.move(self.chip, self.microsteps, up, speed, acc, acc, speed, standing))

    def stop(self, dec: float | None) -> None:
        self._limit, self._run, self._seen = None, 0, None
        self._do(program.stop(hard=dec is None))

    def report_stall_stop(self) -> bool:
        """The executor saw the chip stopped on its stall: the driver reports a stall at
        the poller's next reading, and every one until the next :meth:`watch`."""
        if self._stall_told:
            return False
        self._stall_told = True
        return True
