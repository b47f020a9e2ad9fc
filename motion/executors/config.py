"""[step_thread]: the timing of the step executors, declared beside them.

The section's keys are the executors' own settings, and their defaults are the constants
motion declares for the executors (`SPIN_S` in step_core.py, `LATE_THRESHOLD_S` in latency.py,
`AHEAD_S` and `LEAD_S` in planner.py, `STEP_CORES` in process/rings.py, :class:`RealtimeOptions`,
`STOP_CONFIRM_S` in base.py, the DIR setup time of :class:`AxisSpec`): each written once,
in seconds where motion keeps it, shown here in the key's unit. The daemon's model
(daemon/config/model.py) takes the table into its `Config`; docs/config.md is generated from
it as from the rest.

Pure declarations: no state, no I/O; built once per load on the loading thread.
"""

from __future__ import annotations

from dataclasses import dataclass

from motorctl.hal.spec import AxisSpec
from motorctl.motion.executors.base import STOP_CONFIRM_S
from motorctl.motion.executors.planner import AHEAD_S, LEAD_S
from motorctl.motion.executors.process.rings import STEP_CORES
from motorctl.motion.executors.step_core import SPIN_S
from motorctl.motion.latency import LATE_THRESHOLD_S
from motorctl.motion.rt import RealtimeOptions
from motorctl.schema import boolean, choice, integer, number, section


def _us(seconds: float) -> float:
    """A default motion declares in seconds, in the key's microseconds."""
    return round(seconds * 1e6, 6)


def _ms(seconds: float) -> float:
    """A default motion declares in seconds, in the key's milliseconds."""
    return round(seconds * 1e3, 6)


@section(
    "Timing of the thread that generates step pulses.",
    prose="""\
Timing of the thread that generates step pulses. The defaults suit the mock backend and
most hosts; change them only if the step-timing statistics report late edges.""",
    retired={
        "max_lateness_us": "a late step is judged by the lag it causes, in full steps "
        "(each motor's max_lag_full_steps and start_speed; docs/timing.md), not by a fixed "
        "number of microseconds",
        "driver_poll_ms": "the HAL's one driver poller reads every driver chip now and hands "
        "a fault to the motors as it reads it, with nothing to do with the step thread; its "
        "period is [drivers] poll_ms",
    },
)
@dataclass(frozen=True)
class StepThreadConfig:
    """[step_thread]: timing of the step-generating thread."""

    dir_setup_us: float = number(
        _us(AxisSpec.dir_setup_s), 0, 10000, "DIR is set this long before the next step edge."
    )
    step_pulse_us: float = number(2.0, 0.1, 10000, "Minimum step pulse width.")
    late_threshold_us: float = number(
        _us(LATE_THRESHOLD_S),
        1,
        1e6,
        "A step edge later than this counts as late: the rest of its motor's move slides by "
        "its lateness (or, beyond the motor's max_lag_full_steps, the motor stops).",
    )
    spin_us: float = number(
        _us(SPIN_S), 0, 100000, "Sleep until this long before a deadline, busy-wait the rest."
    )
    priority: int = integer(
        RealtimeOptions.priority,
        0,
        99,
        "SCHED_FIFO priority of the step thread; 0 = do not ask for real-time.",
    )
    lock_memory: bool = boolean(RealtimeOptions.lock_memory, "mlockall() when permitted.")
    switch_interval_us: float = number(
        100.0, 10, 100000, "sys.setswitchinterval() for the daemon process."
    )
    cpu: int = integer(
        RealtimeOptions.cpu,
        -1,
        1023,
        "Pin the step thread to this CPU (the other threads avoid it); -1 = no pinning.",
    )
    executor: str = choice(
        "process",
        ("process", "thread"),
        "Where steps are timed: 'process' = a process of its own (own interpreter and GIL, "
        "SCHED_FIFO, mlockall; the default), 'thread' = a thread of the daemon (single-core "
        "boards, tests).",
    )
    ahead_ms: float = number(
        _ms(AHEAD_S),
        2,
        1000,
        "Steps are planned and handed to the executor this far ahead, topped up every 20 ms "
        "(every half of it when shorter); a soft stop or a new speed still takes over within "
        "a few ms (the handed-over plan is cut at the first "
        "segment boundary after the executor's lead time; docs/timing.md).",
    )
    lead_ms: float = number(
        _ms(LEAD_S),
        1,
        1000,
        "A soft stop, a new speed or any re-plan of a moving motor takes over at the first "
        "segment boundary this long after the command; the re-plan must reach the executor "
        "before then, or the motor stops with E4 'step timing lost (re-plan came N us late)'. "
        "Raise it on a board so loaded that this happens (a stop then takes a little longer "
        "to begin; docs/timing.md).",
    )
    stop_confirm_ms: float = number(
        _ms(STOP_CONFIRM_S),
        1,
        10000,
        "A hard StopMove is answered once the executor confirms the motor stopped (normally "
        "well under 1 ms), so IsReady right after it answers 1; at most this long, then it "
        "is answered all the same (a stalled executor; docs/protocol.md, StopMove).",
    )
    core: str = choice(
        STEP_CORES[0],
        STEP_CORES,
        "The step core of the process executor: 'auto' = the compiled one where it is built "
        "and the backend hands its lines over (GPIO character devices, the mock), else the "
        "Python one with a warning; 'compiled' = that one, or a start error that says why "
        "not; 'python' = the Python reference. The thread executor runs the Python core.",
    )
