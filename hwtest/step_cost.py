"""CPU time per step of both step cores on gpio-sim lines, with real ioctls (inside the VM:
hwtest/run runs it in each guest after the tests, so once per libgpiod API).

Three motors on gpiochip0 (the example's STEP/DIR/ENABLE lines in one request), each core on
a virtual clock over the gpiod backend's own requests: the compiled core writes them with
its ioctls (uAPI v2 GPIO_V2_LINE_SET_VALUES_IOCTL, or v1 GPIOHANDLE_SET_LINE_VALUES_IOCTL),
the Python core through libgpiod's binding. Two patterns: every motor's steps on ticks of
their own (a rise and a fall call per step) and all three on the same ticks (one call
raises all three). Prints microseconds of this process's CPU per step. QEMU emulates the CPU
here (TCG, no KVM): compare the cores and the APIs with each other, not with a board.
Usage (in a guest): MOTORCTL_GPIOD_API=v2 python3 hwtest/step_cost.py
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hwtest.gpiod_harness import GpiodHarness
from motorctl.hal.interfaces import VirtualClock
from motorctl.hal.registry import open_hardware, open_step_io
from motorctl.hal.shm import SharedBlock
from motorctl.motion.executors.compiled_core import CompiledStepCore
from motorctl.motion.executors.core_cells import COUNTER_NAMES, STEPS, CoreInbox
from motorctl.motion.executors.process.rings import Layout, Shared
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.executors.step_core import StepCore
from motorctl.motion.latency import LatencyStats
from tests.support.motor_defaults import motor_limits

API = os.environ.get("MOTORCTL_GPIOD_API", "auto")


def cost(core: str, per_motor: int, shared_ticks: bool) -> float:
    """us of CPU per step: ``per_motor`` steps on each of 3 motors."""
    clock = VirtualClock(time.monotonic() + 3600.0)
    spec = GpiodHarness().spec(3, [], False)
    hw = open_hardware("gpiod", spec, clock)
    io = open_step_io("gpiod", spec, clock, parent=hw)
    limits = [motor_limits(1e-6)] * 3
    start = clock.now_ns() + 1000
    ivs = [10_000] * 3 if shared_ticks else [10_000 + 7 * m for m in range(3)]
    end = start + per_motor * 10_100
    try:
        if core == "compiled":
            layout = Layout(3, len(io.inputs.names))
            shm = SharedBlock.create(layout.size, "motorctl-step-cost")
            shared = Shared(shm, layout)
            compiled = CompiledStepCore(io, limits, shared)
            try:
                for m in range(3):  # flags 0: not watching the end stops, as below
                    assert shared.segs[m].put(start, ivs[m], per_motor, 0, 1, 0, 0)
                compiled.refill()
                t = time.process_time()
                compiled.run_until(end)
                spent = time.process_time() - t
                made = int(shared.counters[STEPS])
            finally:
                compiled.close()
                shared.release()
                shm.close()
        else:
            inbox = CoreInbox(3)
            counters = [0] * len(COUNTER_NAMES)
            python = StepCore(
                io,
                limits,
                inbox,
                lambda e: None,
                positions=[0] * 3,
                levels=[0] * len(io.inputs.names),
                counters=counters,
                stats=LatencyStats(),
            )
            for m in range(3):
                inbox.queues[m].append(StepSegment(start, ivs[m], per_motor, 0, 1, 0, watch=False))
            python.refill()
            t = time.process_time()
            while (d := python.deadline()) is not None:
                clock.advance_to(d / 1e9)
                python.step(d)
            spent = time.process_time() - t
            made = counters[STEPS]
    finally:
        io.close()
        hw.close()
    if made != 3 * per_motor:
        raise SystemExit(f"the {core} core made {made} of {3 * per_motor} steps")
    return spent / made * 1e6


def main() -> int:
    from motorctl.hal.backends.gpiod.chip import load_api

    api = load_api(API)
    print(f"step core CPU per step on gpio-sim, libgpiod {api.name} ({api.version}), QEMU TCG:")
    for shared_ticks, what in ((False, "a call per step"), (True, "3 motors per call")):
        compiled = cost("compiled", 5000, shared_ticks)
        python = cost("python", 500, shared_ticks)
        print(
            f"  {what:<18} compiled {compiled:7.2f} us   python {python:7.2f} us   "
            f"({python / compiled:.1f}x)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
