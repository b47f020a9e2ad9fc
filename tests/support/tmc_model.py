"""A register-level TMC2130/TMC5160 behind a fake of py-spidev's own API.

The model follows the datasheets independently of motorctl's code (its unit formulas and bit
positions are written out here again on purpose, so that a mistake in hal/layers/tmc/ shows):

- 40-bit datagrams, address byte bit 7 = write; the reply's first byte is the SPI status
  (latched at the end of the previous access), its 32 data bits answer the previous datagram:
  a read's register contents, or the data a write carried (the echo).
- IOIN bits 31..24 = version (0x11 TMC2130, 0x30 TMC5160); bit 6 = SD_MODE on the TMC5160.
- GSTAT: reset flag after power-up; TMC2130 clears it on read, the TMC5160 on writing 1s.
- Write-only registers read as 0.
- DRV_STATUS: fault flags injected by the test; short flags stay until TOFF = 0 is written;
  stallGuard flag; stst when not moving; CS_ACTUAL = IRUN or IHOLD.
- TMC5160 ramp generator on a virtual clock: RAMPMODE 0 (position: accelerate with AMAX to
  VMAX, decelerate with DMAX to stop at XTARGET), 1/2 (velocity +/- with AMAX), 3 (hold);
  v[steps/s] = VMAX * fCLK / 2^24, a[steps/s^2] = AMAX * fCLK^2 / 2^41; reference switches
  with polarity, stop enables, latching XACTUAL into XLATCH on the active or the inactive
  edge (SW_MODE latch_l/r_active, bits 5/7; latch_l/r_inactive, bits 6/8), sg_stop; hard
  stops (``wall_at``, ``wall_low_at``): the motor gets no further (XACTUAL counts the lost
  steps on) and stallGuard flags a stall while it pushes into one.
- Units of the ramp generator (TMC5160A datasheet Rev. 1.14, 12.1 "Real World Unit
  Conversion", p. 81, and CHOPCONF.MRES, 6.5.2, p. 51): XACTUAL/XTARGET count the
  sequencer's input steps, each 2^MRES entries of the 1024-entry sine table (256 per full
  step): MSCNT (0x6A) = physical position * 2^MRES mod 1024 (MRES set before moving).

FakeSpiDev implements what py-spidev does: ``open(bus, device)`` opens /dev/spidevB.D
(OSError with ENOENT/EACCES like the kernel), ``mode`` and ``max_speed_hz`` setters raise
OSError(EBADF) before open, ``xfer2(list)`` overwrites the list it is given with the received
bytes and returns that same list.
"""

from __future__ import annotations

import errno
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from motorctl.hal.interfaces import Clock

# -- the datasheet's numbers, written out independently of motorctl.hal.layers.tmc.driver
A_GCONF, A_GSTAT, A_IOIN, A_GLOBALSCALER = 0x00, 0x01, 0x04, 0x0B
A_IHOLD_IRUN, A_TPOWERDOWN, A_TSTEP, A_TCOOLTHRS = 0x10, 0x11, 0x12, 0x14
A_RAMPMODE, A_XACTUAL, A_VACTUAL, A_VSTART, A_A1, A_V1 = 0x20, 0x21, 0x22, 0x23, 0x24, 0x25
A_AMAX, A_VMAX, A_DMAX, A_D1, A_VSTOP, A_TZEROWAIT, A_XTARGET = (
    0x26,
    0x27,
    0x28,
    0x2A,
    0x2B,
    0x2C,
    0x2D,
)
A_SW_MODE, A_RAMP_STAT, A_XLATCH = 0x34, 0x35, 0x36
A_CHOPCONF, A_COOLCONF, A_DRV_STATUS = 0x6C, 0x6D, 0x6F
A_MSCNT = 0x6A

READABLE_2130 = {A_GCONF, A_GSTAT, A_IOIN, A_TSTEP, 0x6A, 0x6B, A_CHOPCONF, A_DRV_STATUS}
READABLE_5160 = READABLE_2130 | {
    A_RAMPMODE,
    A_XACTUAL,
    A_VACTUAL,
    A_XTARGET,
    A_SW_MODE,
    A_RAMP_STAT,
    A_XLATCH,
}

# DRV_STATUS bits
STST, OLB, OLA, S2GB, S2GA, OTPW, OT, STALLGUARD = 31, 30, 29, 28, 27, 26, 25, 24
S2VSB, S2VSA = 13, 12


@dataclass
class TmcModel:
    """One chip. ``clock`` moves the TMC5160's ramp generator (None: nothing moves)."""

    kind: str  # "tmc2130" or "tmc5160"
    clock: Clock | None = None
    clock_hz: float = 12e6
    sd_mode: int = 0  # TMC5160 SD_MODE pin: 1 = STEP/DIR, 0 = ramp generator
    regs: dict[int, int] = field(default_factory=dict)
    faults: set[int] = field(default_factory=set)  # injected DRV_STATUS fault bits
    stall: bool = False  # stallGuard flag in step/dir mode
    step_rate: float = 0.0  # step/s arriving on STEP (step/dir mode): stst and TSTEP
    # physical positions (steps from where the motor was at power-up), ramp mode only:
    # hard stops: the motor gets no further (the steps are lost: XACTUAL counts on) and
    # stalls while it pushes into one
    wall_at: float | None = None  # above
    wall_low_at: float | None = None  # below
    ref_l_at: float | None = None  # REFL active at or below this position
    ref_r_at: float | None = None  # REFR active at or above this position
    dead: bool = False  # no power: MISO floats high
    gstat: int = 0b001  # reset flag set at power-up
    ramp_stat: int = 0
    x: float = 0.0  # XACTUAL
    shift: float = 0.0  # physical position = x + shift (XACTUAL writes renumber)
    v: float = 0.0  # steps/s, signed
    _out: int = 0
    _status: int | None = None  # latched at the end of the previous access
    _t: float | None = None
    log: list[tuple[bytes, bytes]] = field(default_factory=list)

    @property
    def version(self) -> int:
        return 0x11 if self.kind == "tmc2130" else 0x30

    def power_cycle(self) -> None:
        """The chip loses VM/VIO: every register back to 0, the reset flag set."""
        self.regs.clear()
        self.gstat |= 0b001
        self.shift += self.x  # XACTUAL restarts at 0; the motor stays where it is
        self.x = self.v = 0.0

    # -- units (datasheet)
    def v_steps(self, reg: int) -> float:
        return reg * self.clock_hz / 2**24

    def a_steps(self, reg: int) -> float:
        return reg * self.clock_hz**2 / 2**41

    def reg(self, addr: int) -> int:
        return self.regs.get(addr, 0)

    # -- the wire
    def transfer(self, tx: bytes) -> bytes:
        if self.dead:
            return b"\xff" * len(tx)
        if len(tx) != 5:
            raise AssertionError(f"a TMC datagram is 5 bytes, not {len(tx)}")
        self.advance()
        status = self.spi_status() if self._status is None else self._status
        rx = bytes([status]) + self._out.to_bytes(4, "big")
        addr, write = tx[0] & 0x7F, bool(tx[0] & 0x80)
        data = int.from_bytes(tx[1:5], "big")
        if write:
            self._write(addr, data)
            self._out = data
        else:
            self._out = self._read(addr)
        self._status = self.spi_status()
        self.log.append((tx, rx))
        return rx

    def spi_status(self) -> int:
        drv = self.drv_status()
        s = (self.gstat & 1) | (self.gstat & 2) | ((drv >> STALLGUARD & 1) << 2)
        s |= (drv >> STST & 1) << 3
        if self.kind == "tmc5160":
            rs = self.ramp_stat_now()
            s |= ((rs >> 8) & 1) << 4 | ((rs >> 9) & 1) << 5 | (rs & 1) << 6 | ((rs >> 1) & 1) << 7
        return s

    def _read(self, addr: int) -> int:
        readable = READABLE_2130 if self.kind == "tmc2130" else READABLE_5160
        if addr not in readable:
            return 0
        if addr == A_IOIN:
            return self.version << 24 | (self.sd_mode << 6 if self.kind == "tmc5160" else 1 << 6)
        if addr == A_GSTAT:
            g = self.gstat
            if self.kind == "tmc2130":
                self.gstat = 0  # R+C
            return g
        if addr == A_DRV_STATUS:
            return self.drv_status()
        if addr == A_TSTEP:
            return self.tstep()
        if addr == A_XACTUAL:
            return round(self.x) & 0xFFFFFFFF
        if addr == A_MSCNT and self.kind == "tmc5160" and self.sd_mode == 0:
            return self.mscnt()
        if addr == A_VACTUAL:
            return self._vreg() & 0xFFFFFF
        if addr == A_RAMP_STAT:
            return self.ramp_stat_now()
        return self.reg(addr)

    def _write(self, addr: int, data: int) -> None:
        if addr == A_GSTAT:
            if self.kind == "tmc5160":
                self.gstat &= ~data  # R+WC
            return
        if addr == A_RAMP_STAT:
            self.ramp_stat &= ~(data & 0b1_0000_1100_1100)
            return
        if addr == A_XACTUAL:  # renumbers the position; the motor does not move
            new = float(data - (1 << 32) if data >> 31 else data)
            self.shift += self.x - new
            self.x = new
        if addr == A_CHOPCONF and data & 0xF == 0:
            self.faults -= {S2GA, S2GB, S2VSA, S2VSB}  # TOFF = 0 clears latched shorts
        self.regs[addr] = data

    # -- status
    def moving(self) -> bool:
        if self.kind == "tmc5160" and self.sd_mode == 0:
            return self.v != 0
        return self.step_rate > 0

    def tstep(self) -> int:
        mres = self.reg(A_CHOPCONF) >> 24 & 0xF
        rate = abs(self.v) if (self.kind == "tmc5160" and self.sd_mode == 0) else self.step_rate
        if rate <= 0:
            return (1 << 20) - 1
        return min((1 << 20) - 1, int(self.clock_hz / (rate * 2**mres)))

    def stalled(self) -> bool:
        if self.kind == "tmc5160" and self.sd_mode == 0:
            hi, lo = self.wall_at, self.wall_low_at
            pushing_up = hi is not None and self.v > 0 and self.physical >= hi
            pushing_down = lo is not None and self.v < 0 and self.physical <= lo
            return pushing_up or pushing_down or self.stall
        return self.stall

    def drv_status(self) -> int:
        d = 0
        for bit in self.faults:
            if self.kind == "tmc2130" and bit in (S2VSA, S2VSB):
                continue
            d |= 1 << bit
        if not self.moving():
            d |= 1 << STST
        if self.stalled():
            d |= 1 << STALLGUARD
        ihold_irun = self.reg(A_IHOLD_IRUN)
        cs = (ihold_irun >> 8 & 0x1F) if self.moving() else (ihold_irun & 0x1F)
        d |= cs << 16
        d |= 0 if self.stalled() else 300
        return d

    # -- TMC5160 ramp generator
    def mscnt(self) -> int:
        """Where the motor is in the sine table: each ramp step moves it 2^MRES entries."""
        mres = self.reg(A_CHOPCONF) >> 24 & 0xF
        return (round(self.physical) << mres) & 0x3FF

    def _vreg(self) -> int:
        return round(self.v * 2**24 / self.clock_hz)

    @property
    def physical(self) -> float:
        return self.x + self.shift

    @property
    def microstep(self) -> float:
        """The physical position of the microstep XACTUAL reads (the rotor sits on whole
        microsteps): what the reference switches see."""
        return round(self.x) + self.shift

    def switch_active(self, left: bool) -> bool:
        at = self.ref_l_at if left else self.ref_r_at
        if at is None:
            return False
        p = self.microstep
        return p <= at if left else p >= at

    def ramp_stat_now(self) -> int:
        rs = self.ramp_stat & ~0b111_0000_0011
        rs |= int(self.switch_active(True)) | int(self.switch_active(False)) << 1
        sw = self.reg(A_SW_MODE)
        if sw & 1 and self.switch_active(True):
            rs |= 1 << 4
        if sw & 2 and self.switch_active(False):
            rs |= 1 << 5
        mode = self.reg(A_RAMPMODE) & 3
        vmax = self.v_steps(self.reg(A_VMAX))
        target_v = 0.0 if mode == 3 else (vmax if mode != 2 else -vmax)
        if mode == 0:
            if round(self.x) == self._xtarget() and self.v == 0:
                rs |= 1 << 9
            if abs(abs(self.v) - vmax) < 1e-9:
                rs |= 1 << 8
        elif abs(self.v - target_v) < 1e-9 or (mode == 3):
            rs |= 1 << 8
        if self.v == 0:
            rs |= 1 << 10
        return rs

    def _xtarget(self) -> int:
        t = self.reg(A_XTARGET)
        return t - (1 << 32) if t >> 31 else t

    def advance(self) -> None:
        if self.clock is None or self.kind != "tmc5160" or self.sd_mode:
            return
        now = self.clock.now()
        if self._t is None:
            self._t = now
        while self._t < now:
            dt = min(0.0005, now - self._t)
            self._step(dt)
            self._t += dt

    def _step(self, dt: float) -> None:
        mode = self.reg(A_RAMPMODE) & 3
        vmax = self.v_steps(self.reg(A_VMAX))
        amax, dmax = self.a_steps(self.reg(A_AMAX)), self.a_steps(self.reg(A_DMAX))
        sw = self.reg(A_SW_MODE)
        if sw >> 10 & 1 and self.ramp_stat >> 6 & 1:
            self.v = 0.0  # stopped by stallGuard until event_stop_sg is cleared
            return
        if mode == 3:
            pass
        elif mode in (1, 2):
            goal = vmax if mode == 1 else -vmax
            self.v = _approach(self.v, goal, amax * dt)
        else:
            target = self._xtarget()
            dist = target - self.x
            if dist == 0 and self.v == 0:
                return
            direction = 1.0 if dist > 0 or (dist == 0 and self.v < 0) else -1.0
            if self.v * direction < 0:
                self.v = _approach(self.v, 0.0, dmax * dt)
            else:
                speed = abs(self.v)
                speed = _approach(speed, vmax, (amax if speed < vmax else dmax) * dt)
                self.v = direction * min(speed, math.sqrt(2 * dmax * abs(dist)))
                if abs(self.v * dt) >= abs(dist):
                    self.x, self.v = float(target), 0.0
                    return
        for enable, left in ((0, True), (1, False)):
            toward = self.v < 0 if left else self.v > 0
            if sw >> enable & 1 and self.switch_active(left) and (toward or self.v == 0):
                self.v = 0.0  # held at the stop switch while it is active and enabled
                return
        old = self.microstep
        self.x += self.v * dt
        if self.wall_at is not None and self.physical > self.wall_at:
            self.shift -= self.physical - self.wall_at  # against the hard stop: steps lost
        if self.wall_low_at is not None and self.physical < self.wall_low_at:
            self.shift += self.wall_low_at - self.physical
        # reference switches: latch on the active edge (latch_x_active) or the inactive one
        # (latch_x_inactive, the next bit), stop when enabled
        for left, enable, latch, stat_latch in ((True, 0, 5, 2), (False, 1, 7, 3)):
            at = self.ref_l_at if left else self.ref_r_at
            if at is None:
                continue
            was = old <= at if left else old >= at
            now_active = self.switch_active(left)
            if now_active and not was and sw >> latch & 1:
                self.regs[A_XLATCH] = round(at - self.shift) & 0xFFFFFFFF  # in XACTUAL terms
                self.ramp_stat |= 1 << stat_latch
            if was and not now_active and sw >> (latch + 1) & 1:
                # XACTUAL at the inactive edge: the first microstep off the switch
                off = math.floor(at - self.shift) + 1 if left else math.ceil(at - self.shift) - 1
                self.regs[A_XLATCH] = off & 0xFFFFFFFF
                self.ramp_stat |= 1 << stat_latch
            toward = self.v < 0 if left else self.v > 0
            if now_active and sw >> enable & 1 and toward:
                self.v = 0.0  # hard stop (en_softstop = 0)
        if sw >> 10 & 1 and self.stalled() and self.tstep() <= self.reg(A_TCOOLTHRS):
            self.v = 0.0
            self.ramp_stat |= 1 << 6


def _approach(v: float, goal: float, dv: float) -> float:
    if v < goal:
        return min(goal, v + dv)
    return max(goal, v - dv)


# ------------------------------------------------------------------------------ py-spidev


@dataclass
class FakeKernel:
    """The /dev/spidevB.C devices there are, each a chip model; errors to inject."""

    chips: dict[tuple[int, int], TmcModel] = field(default_factory=dict)
    no_permission: set[tuple[int, int]] = field(default_factory=set)
    fail_xfers: int = 0  # the next this-many xfer2 calls raise OSError(EIO)
    opened: list[FakeSpiDev] = field(default_factory=list)

    def factory(self) -> Callable[[], FakeSpiDev]:
        return lambda: FakeSpiDev(self)


class FakeSpiDev:
    """py-spidev's ``SpiDev`` as it behaves (spidev_module.c), in front of a FakeKernel."""

    def __init__(self, kernel: FakeKernel) -> None:
        self._kernel = kernel
        self._fd = -1
        self._mode = 0
        self._speed = 0
        self._bits = 8
        self._chip: TmcModel | None = None

    def open(self, bus: int, device: int) -> None:
        path = f"/dev/spidev{bus}.{device}"
        chip = self._kernel.chips.get((bus, device))
        if chip is None:
            raise OSError(errno.ENOENT, "No such file or directory")
        if (bus, device) in self._kernel.no_permission:
            raise OSError(errno.EACCES, "Permission denied")
        del path
        self._fd = 3
        self._mode = 0  # read from the device by SPI_IOC_RD_MODE
        self._speed = 500_000
        self._chip = chip
        self._kernel.opened.append(self)

    def close(self) -> None:
        self._fd = -1
        self._chip = None

    @property
    def mode(self) -> int:
        return self._mode & 3

    @mode.setter
    def mode(self, value: int) -> None:
        if not isinstance(value, int):
            raise TypeError("The mode attribute must be an integer")
        if value > 3:
            raise TypeError("The mode attribute must be an integerbetween 0 and 3.")
        if self._fd < 0:
            raise OSError(errno.EBADF, "Bad file descriptor")
        self._mode = value

    @property
    def bits_per_word(self) -> int:
        return self._bits

    @bits_per_word.setter
    def bits_per_word(self, value: int) -> None:
        if not isinstance(value, int):
            raise TypeError("The bits_per_word attribute must be an integer")
        if value < 8 or value > 16:
            raise TypeError("invalid bits_per_word (8 to 16)")
        if self._fd < 0:
            raise OSError(errno.EBADF, "Bad file descriptor")
        self._bits = value

    @property
    def max_speed_hz(self) -> int:
        return self._speed

    @max_speed_hz.setter
    def max_speed_hz(self, value: int) -> None:
        if not isinstance(value, int):
            raise TypeError("The max_speed_hz attribute must be an integer")
        if self._speed != value:
            if self._fd < 0:
                raise OSError(errno.EBADF, "Bad file descriptor")
            self._speed = value

    def xfer2(self, values: list[int]) -> list[int]:
        if self._fd < 0 or self._chip is None:
            raise OSError(errno.EBADF, "Bad file descriptor")
        if len(values) == 0:
            raise TypeError("Empty argument list.")
        if self._kernel.fail_xfers > 0:
            self._kernel.fail_xfers -= 1
            raise OSError(errno.EIO, "Input/output error")
        tx = bytes(v & 0xFF for v in values)
        if self._mode != 3:  # sampled on the wrong edge: every bit arrives one place late
            tx = (int.from_bytes(tx, "big") >> 1).to_bytes(len(tx), "big")
        rx = self._chip.transfer(tx)
        for i, b in enumerate(rx):
            values[i] = b  # py-spidev writes the received bytes into the list passed in
        return values
