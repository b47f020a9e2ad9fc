"""The real-time step thread: executes the engine's deadlines on the monotonic clock.

It sleeps (on an event, so new work wakes it) until ``spin_s`` before the next
deadline and busy-waits the rest. It asks for SCHED_FIFO and mlockall when
permitted and warns once when not. The GC policy keeps collections out of
motion: automatic collection is off while anything moves and back on (with a
collection done by the caller's thread) when all is idle.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import threading

from motorctl.hal.interfaces import Clock
from motorctl.motion.engine import MotionEngine

log = logging.getLogger("motorctl.steps")

_MCL_CURRENT = 1
_MCL_FUTURE = 2


def lock_memory() -> str | None:
    """mlockall(MCL_CURRENT | MCL_FUTURE); returns why not, or None on success."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return "libc not found"
    libc = ctypes.CDLL(libc_name, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        return os.strerror(ctypes.get_errno())
    return None


def set_realtime(priority: int) -> str | None:
    """SCHED_FIFO at ``priority`` for the calling thread; returns why not, or None."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError) as exc:
        return str(exc)
    return None


class GcPolicy:
    """Automatic GC off while anything moves; objects alive at ready are frozen."""

    def ready(self) -> None:
        gc.collect()
        gc.freeze()

    def motion(self, active: bool) -> None:
        if active:
            gc.disable()
        else:
            gc.enable()


class StepThread:
    def __init__(
        self,
        engine: MotionEngine,
        clock: Clock,
        *,
        spin_s: float = 200e-6,
        priority: int = 50,
        lock_memory: bool = True,
        cpu: int = -1,
        name: str = "motorctl-steps",
    ) -> None:
        if clock.is_virtual:
            raise ValueError("the step thread runs on a real clock; tests use engine.run_until")
        self.engine = engine
        self.clock = clock
        self.spin_s = spin_s
        self.priority = priority
        self.lock_memory = lock_memory
        self.cpu = cpu
        self.warnings: list[str] = []
        self.realtime = False
        self._stop = threading.Event()
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()
        self._started.wait()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self) -> None:
        self._stop.set()
        self.engine.wake.set()
        self._thread.join()

    def _setup(self) -> None:
        if self.cpu >= 0:
            try:
                os.sched_setaffinity(0, {self.cpu})
            except OSError as exc:
                self.warnings.append(f"cannot pin the step thread to CPU {self.cpu}: {exc}")
        if self.lock_memory:
            why = lock_memory()
            if why is not None:
                self.warnings.append(f"mlockall not permitted ({why}): memory may be paged out")
        if self.priority > 0:
            why = set_realtime(self.priority)
            if why is None:
                self.realtime = True
            else:
                self.warnings.append(
                    f"SCHED_FIFO priority {self.priority} not permitted ({why}): "
                    "step timing is best effort"
                )
        for w in self.warnings:
            log.warning("%s", w)

    def _run(self) -> None:
        self._setup()
        self._started.set()
        engine, clock, lock, wake = self.engine, self.clock, self.engine.lock, self.engine.wake
        spin = self.spin_s
        while not self._stop.is_set():
            wake.clear()
            with lock:
                step = engine.next_step_deadline()
                coarse = engine.next_coarse_deadline()
            if step is None or coarse < step - spin:
                # Nothing to spin for before the coarse deadline: just sleep until it.
                wait = coarse - clock.now()
                if wait > 0 and wake.wait(wait):
                    continue
                with lock:
                    engine.service(clock.now())
                continue
            wait = step - spin - clock.now()
            if wait > 0 and wake.wait(wait):
                continue  # new work may have an earlier deadline
            now = clock.now()
            while now < step and not wake.is_set():
                now = clock.now()
            with lock:
                engine.service(clock.now())
