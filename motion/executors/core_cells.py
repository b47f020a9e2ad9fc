"""The step core's mailbox and cells: what the planner hands it (:class:`CoreInbox`) and
what it publishes for others to read (the counters and the per-motor cells, by index and
name). Both cores keep this layout (csrc/stepcore.h mirrors the indices); the planner, the
shared-memory rings and the executors' health read it without the core itself.

Holds no state but the inbox's deques: one producer (the planner's thread) and one
consumer (the core's owner, step_core.py says which), safe under the GIL as they are.
"""

from __future__ import annotations

from collections import deque

from motorctl.motion.executors.segments import StepSegment

# counters cells
PROGRESS, STEPS, TIMING_LOST, IO_ERRORS, ENDSTOPS, DISCARDED, MIN_GAP, BAD_RECORDS = range(8)
COUNTER_NAMES = (
    "progress",
    "steps",
    "timing_lost",
    "io_errors",
    "endstops",
    "segments_discarded",  # segments of a replaced or stopped plan, never stepped
    "min_gap_ns",
    "bad_records",
)

# per motor cells (``motor_cells``: MOTOR_CELLS per motor, motor m's at m * MOTOR_CELLS)
SHIFT, ABSORBED, WORST_LATE, WORST_LAG, LAG_FAULTS = range(5)
MOTOR_CELL_NAMES = ("shift_ns", "late_absorbed", "worst_late_ns", "worst_lag_ufs", "lag_faults")
MOTOR_CELLS = len(MOTOR_CELL_NAMES)
#: worst lag cell unit: millionths of a full step
LAG_UNIT = 1_000_000


class CoreInbox:
    """What the planner hands the core: per-motor segment queues and hard stops; and the
    records the transport found bad (``faults``: (motor or -1 for every motor, detail);
    the shared-memory rings' only, process/child.py)."""

    def __init__(self, motors: int) -> None:
        self.queues: list[deque[StepSegment]] = [deque() for _ in range(motors)]
        self.stops: deque[tuple[int, int, int]] = deque()  # (motor, gen, cut or -1)
        self.faults: deque[tuple[int, str]] = deque()

    def pull(self) -> None:
        """Move pending work from the transport into the deques (in-process: nothing)."""
