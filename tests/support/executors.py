"""Executors for tests: a stand-in that records what it is asked (``RecordingExecutor``),
the ramp executor over TMC5160 register models on the fake SPI bus (``RampRig``), the
process step executor over the mock world (``process_executor``), and the shared-memory
rings' slots written by hand (``show_slot``: what a weakly ordered CPU may show a
consumer)."""

from __future__ import annotations

import os
import pickle
import socket
import struct
import subprocess
import sys
from collections.abc import Callable
from typing import Any

from motorctl.hal.backends.mock.backend import build
from motorctl.hal.interfaces import Hardware, MonotonicClock
from motorctl.hal.layers.tmc.settings import TmcSettings
from motorctl.hal.layers.tmc.tmc5160 import TMC5160, RefSwitches, Tmc5160
from motorctl.hal.spec import AxisSpec, HardwareSpec
from motorctl.motion.executors.base import (
    Committed,
    ExecEvent,
    ExecEventKind,
    Executor,
    ExecutorHealth,
)
from motorctl.motion.executors.chip_ramp import RampExecutor
from motorctl.motion.executors.process.parent import ProcessStepExecutor
from motorctl.motion.executors.process.rings import Ring, ring_size
from motorctl.motion.executors.process.start import (
    BOOTSTRAP,
    WaitingInterpreter,
    import_path,
    package_location,
)
from motorctl.motion.profile import Trajectory
from motorctl.motion.rt import RealtimeOptions
from motorctl.motion.types import Ramp
from tests.support.motor_defaults import motor_limits
from tests.support.spi_bench import SpiBench
from tests.support.tmc_model import TmcModel


class RecordingExecutor(Executor):
    """A stand-in executor that records every command and answers from its own state.

    ``calls``: ("follow", motor, gen, traj, endstops, release), ("stop", motor, gen), ("committed",
    motor, now), in order. Positions (``positions``) and end-stop levels (``endstops``:
    (motor, direction) -> active) are the test's to set; a follow returns ``moves`` (False:
    the plan makes no step). ``stop`` returns the position at once (the position is final)
    unless ``stops_at_once`` is False: then None, and the test reports STOPPED (``report``).
    ``pending``: the events the next :meth:`events` returns.
    """

    def __init__(self, motors: int, *, stops_at_once: bool = True) -> None:
        super().__init__(motors)
        self.calls: list[tuple[object, ...]] = []
        self.pending: list[ExecEvent] = []
        self.positions = [0] * motors
        self.endstops: dict[tuple[int, int], bool] = {}
        self.stops_at_once = stops_at_once
        self.moves = True
        self.progress = 0

    def follow(
        self,
        motor: int,
        traj: Trajectory,
        ramp: Ramp,
        gen: int,
        endstops: bool = True,
        release: bool = False,
    ) -> bool:
        self.calls.append(("follow", motor, gen, traj, endstops, release))
        return self.moves

    def stop(self, motor: int, gen: int) -> int | None:
        self.calls.append(("stop", motor, gen))
        return self.positions[motor] if self.stops_at_once else None

    def committed(self, motor: int, now: float) -> Committed:
        self.calls.append(("committed", motor, now))
        p = self.positions[motor]
        return Committed(now, float(p), 0.0, p)

    def service(self, now: float) -> float:
        return now + 1.0

    def events(self) -> list[ExecEvent]:
        out, self.pending = self.pending, []
        return out

    def events_waiting(self) -> bool:
        return bool(self.pending)

    def report(
        self,
        kind: ExecEventKind,
        motor: int,
        gen: int,
        *,
        t: float = 0.0,
        direction: int = 0,
        speed: float = 0.0,
        detail: str = "",
        mark: int = 0,
    ) -> ExecEvent:
        """An event of ``motor`` at its position, queued for :meth:`events`."""
        ev = ExecEvent(kind, motor, gen, self.positions[motor], t, direction, speed, detail, mark)
        self.pending.append(ev)
        return ev

    def planned(self, motor: int) -> bool:
        return False

    def position(self, motor: int) -> int:
        return self.positions[motor]

    def endstop_active(self, motor: int, direction: int) -> bool:
        return self.endstops.get((motor, direction), False)

    def health(self) -> ExecutorHealth:
        return ExecutorHealth(True, self.progress)

    def of(self, kind: str) -> list[tuple[object, ...]]:
        """The recorded calls of one kind ("follow", "stop", "committed")."""
        return [c for c in self.calls if c[0] == kind]


#: The chips' settings on the ramp rig.
RAMP_SETTINGS = TmcSettings(
    chip=TMC5160, run_current=2.0, hold_current=1.0, microsteps=16, stall_min_speed=500.0
)


class RampRig:
    """``n`` TMC5160 models on /dev/spidev0.x (tests/support/spi_bench.py), started as ramp
    chips, and a RampExecutor over them, on the bench's virtual clock."""

    def __init__(self, n: int = 1) -> None:
        self.bench = SpiBench()
        self.clock = self.bench.clock
        self.kernel = self.bench.kernel
        self.models: list[TmcModel] = []
        self.chips: list[Tmc5160] = []
        for i in range(n):
            model = self.bench.chip("tmc5160", cs=i)
            device = self.bench.device(i, speed=1_000_000)
            chip = Tmc5160(f"m{i}", device, RAMP_SETTINGS, RefSwitches())
            chip.start()
            self.models.append(model)
            self.chips.append(chip)
        self.ex = RampExecutor(self.chips, self.clock, poll_s=0.002, idle_poll_s=0.02)
        self.ex.start()
        self.seen: list[ExecEvent] = []

    def run(self, until: Callable[[], bool], limit_s: float) -> float:
        """Service the executor on the virtual clock until ``until()``; the time it took."""
        t0 = self.clock.now()
        while True:
            self.seen += self.ex.events()
            if until():
                return self.clock.now() - t0
            assert self.clock.now() - t0 < limit_s, f"not done within {limit_s} s"
            nxt = self.ex.service(self.clock.now())
            self.clock.advance_to(max(nxt, self.clock.now() + 1e-4))

    def kinds(self) -> list[ExecEventKind]:
        return [e.kind for e in self.seen]


def process_executor(
    backend: str = "mock",
    *,
    motors: int = 1,
    core: str = "auto",
    start_timeout_s: float = 30.0,
    rt: RealtimeOptions | None = None,
    process: WaitingInterpreter | None = None,
) -> tuple[Hardware, ProcessStepExecutor]:
    """The process step executor for ``motors`` motors of ``backend`` (on the real clock,
    not started: the caller starts it and closes both); ``rt``: the real time it asks for
    (none by default); ``process``: its interpreter (else one started as the daemon does)."""
    spec = HardwareSpec(axes=(AxisSpec(),) * motors)
    hw = build(spec, MonotonicClock())
    limits = [motor_limits(1e-4)] * motors
    return hw, ProcessStepExecutor(
        hw,
        backend,
        spec,
        limits,
        start_timeout_s=start_timeout_s,
        core=core,
        rt=rt,
        process=process,
    )


#: A prelude for the executor's interpreter: the kernel refuses SCHED_FIFO there (EPERM at
#: os.sched_setscheduler, the syscall's own Python API), as a kernel without the limit, or
#: with RT group scheduling, does; nothing else of the executor is changed.
REFUSE_SCHED_FIFO = """\
import errno, os
def _refused(pid, policy, param):
    raise PermissionError(errno.EPERM, "Operation not permitted")
os.sched_setscheduler = _refused
"""


def interpreter_with(prelude: str) -> WaitingInterpreter:
    """The step executor's interpreter started as start.py starts it (its bootstrap, the
    daemon's PID and sys.path first), ``prelude`` run before the bootstrap."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        proc = subprocess.Popen(
            [sys.executable, "-I", "-c", prelude + BOOTSTRAP], stdin=theirs.fileno()
        )
    finally:
        theirs.close()
    ours.send(pickle.dumps((os.getpid(), import_path(), package_location())))
    return WaitingInterpreter(proc, ours)


# ---------------------------------------------------------------- the rings' slots by hand


def scratch_ring(rec: struct.Struct, cap: int) -> Ring:
    """A ring of ``cap`` records of ``rec`` in plain memory (no shared block)."""
    return Ring(memoryview(bytearray(ring_size(rec, cap))), 0, rec, cap)


def slot_offset(ring: Ring, index: int) -> int:
    """Offset of the slot that record number ``index`` (0-based) uses."""
    return ring.base + (index % ring.cap) * ring.slot


def slot_bytes(ring: Ring, index: int, fields: tuple[Any, ...]) -> bytes:
    """The bytes a complete put of ``fields`` as record ``index`` leaves in its slot."""
    scratch = scratch_ring(ring.rec, ring.cap)
    scratch.cells[0] = scratch.cells[1] = index
    assert scratch.put(*fields)
    at = slot_offset(scratch, index)
    return bytes(scratch.buf[at : at + scratch.slot])


def show_slot(ring: Ring, index: int, content: bytes) -> None:
    """Make the consumer see ``content`` in record ``index``'s slot and the head past it, as
    a weakly ordered CPU may show it a slot being written (any mix of old and new bytes)."""
    at = slot_offset(ring, index)
    ring.buf[at : at + ring.slot] = content
    ring.cells[0] = max(ring.cells[0], index + 1)
