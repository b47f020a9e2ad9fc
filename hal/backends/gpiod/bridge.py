"""The gpiod backend's H-bridge: IN1/IN2 (and EN) lines, or a kernel PWM channel on EN.

Threads: the motion engine (under its lock) owns the bridge; a reversal's dead time is
finished by the bridge's own small timer thread. Calls block only on GPIO ioctls and sysfs
writes (PWM).
"""

from __future__ import annotations

import logging
import os
import threading

from motorctl.hal.backends.gpiod.chip import LineRequest
from motorctl.hal.backends.gpiod.wiring import DcWiring, PwmWiring
from motorctl.hal.interfaces import BridgeState, Clock, DcBridge, HalError

log = logging.getLogger("motorctl.gpiod")


class PwmChannel:
    """A kernel PWM channel through sysfs (``/sys/class/pwm/pwmchipN/pwmM``)."""

    def __init__(self, w: PwmWiring) -> None:
        self.w = w
        chip = os.path.join(w.sysfs, f"pwmchip{w.chip}")
        self.dir = os.path.join(chip, f"pwm{w.channel}")
        try:
            if not os.path.isdir(self.dir):
                self._write(os.path.join(chip, "export"), str(w.channel))
            self._write(os.path.join(self.dir, "enable"), "0")
            self._write(os.path.join(self.dir, "duty_cycle"), "0")
            self._write(os.path.join(self.dir, "period"), str(w.period_ns))
            self._write(os.path.join(self.dir, "enable"), "1")
        except OSError as exc:
            raise HalError(
                f"dc.pwm: cannot set up {self.dir}: {exc.strerror or exc}; enable the "
                "PWM overlay (dtoverlay=pwm on a Raspberry Pi) and give the daemon's "
                "user write access (group gpio)"
            ) from exc

    @staticmethod
    def _write(path: str, value: str) -> None:
        with open(path, "w") as f:
            f.write(value)

    def set(self, fraction: float) -> None:
        duty = round(self.w.period_ns * min(1.0, max(0.0, fraction)))
        self._write(os.path.join(self.dir, "duty_cycle"), str(duty))

    def close(self) -> None:
        try:
            self.set(0.0)
            self._write(os.path.join(self.dir, "enable"), "0")
        except OSError as exc:
            log.warning("dc.pwm: %s", exc)


#: IN1, IN2, EN per state
BRIDGE_LEVELS = {
    BridgeState.FORWARD: (True, False, True),
    BridgeState.REVERSE: (False, True, True),
    BridgeState.BRAKE: (True, True, True),
    BridgeState.COAST: (False, False, False),
}


class GpiodBridge(DcBridge):
    """An H-bridge on IN1/IN2 (+EN or PWM). A reversal passes through ``reverse_via`` for the
    dead time; the bridge's timer thread applies the new direction when it is over."""

    def __init__(
        self,
        req: LineRequest,
        w: DcWiring,
        offsets: tuple[int, int, int | None],
        pwm: PwmChannel | None,
        clock: Clock,
    ) -> None:
        super().__init__()
        self.req = req
        self.w = w
        self.in1, self.in2, self.en = offsets
        self.pwm = pwm
        self.clock = clock
        self.driven = BridgeState.COAST
        self.via = BridgeState.COAST if w.reverse_via == "coast" else BridgeState.BRAKE
        self._cond = threading.Condition()
        self._pending: tuple[float, BridgeState] | None = None
        self._thread: threading.Thread | None = None
        self._closed = False

    def _drive(self, state: BridgeState) -> None:
        a, b, en = BRIDGE_LEVELS[state]
        values = {self.in1: a, self.in2: b}
        if self.en is not None:
            values[self.en] = en
        self.req.set_values(values)
        if self.pwm is not None:
            run = state in (BridgeState.FORWARD, BridgeState.REVERSE)
            self.pwm.set(self.pwm.w.duty if run else (1.0 if en else 0.0))
        self.driven = state

    def _apply(self, state: BridgeState) -> None:
        with self._cond:
            self._pending = None
            runs = (BridgeState.FORWARD, BridgeState.REVERSE)
            reversal = state in runs and self.driven in runs and state is not self.driven
            if reversal and self.w.dead_time_ms > 0:
                self._drive(self.via)
                self._pending = (self.clock.now() + self.w.dead_time_ms / 1000.0, state)
                if self._thread is None:
                    self._thread = threading.Thread(
                        target=self._run, name="dc-dead-time", daemon=True
                    )
                    self._thread.start()
                self._cond.notify()
            else:
                self._drive(state)

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                if self._pending is None:
                    self._cond.wait()
                    continue
                due, state = self._pending
                left = due - self.clock.now()
                if left > 0:
                    self._cond.wait(left)
                    continue
                self._pending = None
                self._drive(state)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._pending = None
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(5.0)
        if self.pwm is not None:
            self.pwm.close()
