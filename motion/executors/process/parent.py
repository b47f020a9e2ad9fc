"""The ``process`` step executor, the daemon's side: the planner here, the step core in a
process of its own (``child.py``), over a block of shared memory (``rings.py``).

:class:`ProcessStepExecutor` is a :class:`~motorctl.motion.executors.planner.StepExecutor`
whose transport to the core is the shared block: it makes the block, hands it with its
parameters and descriptors to an interpreter started for it (``start.py``: started early by
``motorctld``, or here), writes the segment and stop rings, drains the event ring and reads
the child's cells as snapshots; once the child is ready, what real time it got (its
real-time report in the block: :meth:`ProcessStepExecutor.realtime`). Segments that do not
fit a full ring wait in ``pending`` and go at the next top-up; a full stop ring raises
:class:`~motorctl.hal.interfaces.HalError` (stops are few: the child is not taking them).

Two pipes carry only wake-up bytes, never messages: the daemon's wake-up pipe (a byte after
new work: one per planner pass) and the child's event pipe, which the event thread waits
on. The child is the event pipe's only writer, so its end there (EOF) says at once that the
child is gone, however it ended: the event thread reports DIED, every motor faults (E4,
position lost) and health says why; the service then exits non-zero.

Owners: the planner side (the engine lock) writes the segment and stop rings and drains the
event ring; the event thread (``motorctl-exec-watch``) only waits on the event pipe and
wakes the planner.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import replace

from motorctl.hal.interfaces import HalError, Hardware
from motorctl.hal.shm import SharedBlock
from motorctl.hal.spec import HardwareSpec
from motorctl.motion.executors.base import AxisLimits, ExecEvent, ExecEventKind, ExecutorHealth
from motorctl.motion.executors.core_cells import COUNTER_NAMES
from motorctl.motion.executors.planner import AHEAD_S, LEAD_S, StepExecutor
from motorctl.motion.executors.process.rings import (
    CORE_CELL,
    CORES,
    EXIT_NO_CORE,
    READY_CELL,
    RUN_CELL,
    STEP_CORES,
    Layout,
    Shared,
    decode_event,
    segment_fields,
)
from motorctl.motion.executors.process.start import WaitingInterpreter
from motorctl.motion.executors.segments import StepSegment
from motorctl.motion.executors.step_core import SPIN_S
from motorctl.motion.latency import CELLS, LATE_THRESHOLD_S, LatencyStats
from motorctl.motion.rt import RealtimeOptions, RealtimeReport

log = logging.getLogger("motorctl.executor")


class ProcessStepExecutor(StepExecutor):
    """The planner in the daemon, the step core in its own real-time process."""

    def __init__(
        self,
        hw: Hardware,
        backend: str,
        spec: HardwareSpec,
        limits: Sequence[AxisLimits],
        *,
        ahead_s: float = AHEAD_S,
        lead_s: float = LEAD_S,
        max_error_s: float = 5e-6,
        spin_s: float = SPIN_S,
        late_threshold_s: float = LATE_THRESHOLD_S,
        rt: RealtimeOptions | None = None,
        start_timeout_s: float = 30.0,
        process: WaitingInterpreter | None = None,
        core: str = STEP_CORES[0],
    ) -> None:
        """``process``: an executor process started earlier (``daemon/start/launch.py``), else
        one is started here. ``core``: the step core it runs, "auto" (the compiled one where
        it is built and the backend hands over its lines, else the Python one, with a
        warning), "compiled" (else it cannot start) or "python"."""
        if hw.clock.is_virtual:
            raise ValueError(
                "the process executor runs on the real clock; tests on a virtual "
                "clock use the thread executor"
            )
        super().__init__(hw.clock, limits, ahead_s=ahead_s, lead_s=lead_s, max_error_s=max_error_s)
        self.backend = backend
        self.spec = replace(spec, options={**spec.options, **hw.step_io_options})
        self.rt = rt or RealtimeOptions(priority=0, lock_memory=False)
        self.spin_s = spin_s
        self.coalesce_s = max_error_s  # a step may share an earlier pulse within the error
        self.late_threshold_s = late_threshold_s
        self.start_timeout_s = start_timeout_s
        self.core = core
        #: the step core the process runs ("compiled", "python"; None until started) and
        #: its note (why not the compiled one)
        self.core_name: str | None = None
        self.core_note = ""
        #: what real time the process got (None until started)
        self.realtime_report: RealtimeReport | None = None
        motors = len(limits)
        self.lines = 2 * len(spec.axes)
        self.layout = Layout(motors, self.lines)
        # zero-filled, anonymous: nothing to remove, whatever happens (see the module's doc)
        self.shm = SharedBlock.create(self.layout.size, "motorctl-executor")
        self.shared = Shared(self.shm, self.layout)
        self.stats = LatencyStats(late_threshold_s, self.shared.latency)
        self.motor_cells = self.shared.motor_cells
        self._step_io_fds = dict(hw.step_io_fds)
        # raw bytes on two pipes: only wake-ups, never messages. The child's ends (wake
        # read, event write) are closed here once it has them: the event pipe's end (EOF)
        # then says the child is gone
        self._wake_r, self._wake_w = os.pipe()
        self._event_r, self._event_w = os.pipe()
        self._child_fds: list[int] = [self._wake_r, self._event_w]
        os.set_blocking(self._wake_w, False)
        os.set_blocking(self._event_r, False)
        self._batching = False  # in service(): one wake-up byte for all its pushes
        self._kick_owed = False
        self.proc: subprocess.Popen[bytes] | None = None
        self._spawned = time.monotonic()  # (or earlier: a process started before)
        self.died: str | None = None
        self._died_reported = False
        self._closing = False
        self._watcher: threading.Thread | None = None
        self._closed: tuple[list[int], dict[str, int]] | None = None
        self.pending: list[list[StepSegment]] = [[] for _ in range(motors)]
        # the child runs from now on (if it was not started already, it starts now), while
        # the daemon builds the rest; start() waits for it
        self.shared.header[RUN_CELL] = 1
        try:
            self._hand_over(process)
        except BaseException:
            self.close()
            raise

    # -- lifecycle -----------------------------------------------------------------------
    def _hand_over(self, process: WaitingInterpreter | None) -> None:
        """The process its parameters and descriptors (our copies are closed then)."""
        if process is None:
            try:
                process = WaitingInterpreter.start()
            except OSError as exc:
                raise HalError(
                    f"cannot start the step executor process ({sys.executable}): {exc}"
                ) from exc
            self._spawned = time.monotonic()
        self.proc = process.proc
        assert self.shm.fd is not None
        fds = {
            "shm_fd": self.shm.fd,
            "wake_fd": self._wake_r,
            "event_fd": self._event_w,
            **self._step_io_fds,
        }
        params = {
            "fds": list(fds),
            "step_io_fds": list(self._step_io_fds),
            "motors": self.layout.motors,
            "lines": self.lines,
            "backend": self.backend,
            "spec": self.spec,
            "limits": list(self.limits),
            "rt": self.rt,
            "spin_s": self.spin_s,
            "late_threshold_s": self.late_threshold_s,
            "coalesce_s": self.coalesce_s,
            "core": self.core,
        }
        with contextlib.suppress(OSError):  # it is gone already: start() says how it ended
            process.hand_over(params, list(fds.values()))
        self._forget_child_fds()  # the child has its own now

    def start(self) -> None:
        """Wait until the child is ready (at most ``start_timeout_s``), then watch it."""
        proc = self.proc
        if proc is None or self._watcher is not None or self._closed is not None:
            raise RuntimeError("the step executor process starts once, before close()")
        # READY is read only after the child's byte on the event pipe (child.py, run_child): the
        # end-stop map it wrote before is then visible here on ARM64 too
        deadline = self._spawned + self.start_timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                proc.kill()
                proc.wait(5)
                raise HalError(
                    f"the step executor process did not start within {self.start_timeout_s:.0f} s"
                )
            if not select.select([self._event_r], [], [], left)[0]:
                continue
            # the child's first byte on this pipe; event bytes after it are the watcher's
            try:
                byte = os.read(self._event_r, 1)
            except BlockingIOError:
                continue
            if byte == b"":  # its end closed: it exited
                code = proc.wait()
                note = self._note()
                if code == EXIT_NO_CORE and note:
                    raise HalError(f"the step executor cannot start: {note}")
                raise HalError(
                    f"the step executor process exited at start (code {code}); see the log above"
                )
            if self.shared.header[READY_CELL]:
                break
        self.core_name = CORES[self.shared.header[CORE_CELL]] or None
        self.core_note = self._note()
        self.realtime_report = self._realtime()
        if self.core_name == "python" and self.core != "python":
            log.warning("step core: python (%s)", self.core_note)
        else:
            log.info("step core: %s (%s)", self.core_name, self.core_note)
        self._watcher = threading.Thread(
            target=self._watch, name="motorctl-exec-watch", daemon=True
        )
        self._watcher.start()

    def _note(self) -> str:
        """The child's note (written before READY or before it exited)."""
        return bytes(self.shared.note).rstrip(b"\0").decode(errors="replace")

    def _realtime(self) -> RealtimeReport | None:
        """The child's real-time report (written before READY); None, logged, when it is
        not one (a child of another version)."""
        text = bytes(self.shared.realtime).rstrip(b"\0")
        try:
            return RealtimeReport.from_dict(json.loads(text))
        except ValueError as exc:
            log.error("the step executor's real-time report cannot be read: %s", exc)
            return None

    def step_core(self) -> str | None:
        return self.core_name

    def realtime(self) -> RealtimeReport | None:
        return self.realtime_report

    def _forget_child_fds(self) -> None:
        """Close this process's copies of the child's descriptors (its pipe ends, the block's
        memfd; the mapping stays)."""
        for fd in self._child_fds:
            os.close(fd)
        self._child_fds = []
        self.shm.forget_fd()

    def _watch(self) -> None:
        """Wake the planner on events; notice at once when the child dies: the event pipe
        ends (its only writer is gone, however it ended)."""
        proc = self.proc
        assert proc is not None
        while True:
            select.select([self._event_r], [], [])
            try:
                data = os.read(self._event_r, 4096)
            except BlockingIOError:
                continue
            if data:
                self.on_event()
                continue
            code = proc.wait()
            if not self._closing:
                self.died = f"step executor process {proc.pid} died (exit code {code})"
                log.error("%s: every motor faults, positions lost", self.died)
            self.on_event()
            return

    def close(self) -> None:
        if self._closed is not None:
            return
        self._closing = True
        self.shared.header[RUN_CELL] = 0
        self._kick()
        if self.proc is not None:
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if self._watcher is not None:
            self._watcher.join(5)
            self._watcher = None
        # what is read after close comes from plain copies, not the block
        self._closed = ([int(x) for x in self.shared.positions], self._counters())
        cells = [int(self.shared.latency[i]) for i in range(CELLS)]
        self.stats = LatencyStats(self.late_threshold_s, cells)
        self.motor_cells = [int(x) for x in self.shared.motor_cells]
        self.shared.release()
        self._forget_child_fds()  # not started: they are still here
        self.shm.close()
        for fd in (self._wake_w, self._event_r):
            os.close(fd)

    @property
    def pid(self) -> int | None:
        """The executor process's PID (status, benchmarks)."""
        return None if self.proc is None else int(self.proc.pid)

    def kill_for_test(self, sig: int) -> None:
        """Send ``sig`` to the executor process (tests and benchmarks: stalls, death)."""
        assert self.proc is not None
        os.kill(self.proc.pid, sig)

    # -- the transport ---------------------------------------------------------------------
    def _push(self, motor: int, segments: list[StepSegment]) -> None:
        if self._closed is not None:
            return  # closed: nothing moves any more
        ring = self.shared.segs[motor]
        pending = self.pending[motor]
        pending.extend(segments)
        sent = 0
        for seg in pending:
            if not ring.put(*segment_fields(seg)):
                break
            sent += 1
        del pending[:sent]
        self._kick()

    def _push_stop(self, motor: int, gen: int, cut: int = -1) -> None:
        if self._closed is not None:
            return
        self.pending[motor] = [
            s for s in self.pending[motor] if s.gen > gen or (cut >= 0 and s.first < cut)
        ]
        if not self.shared.stops.put(motor, gen, cut):
            raise HalError("the step executor's stop ring is full")
        self._kick()

    def _kick(self) -> None:
        if self._batching:
            self._kick_owed = True
            return
        self._kick_owed = False
        with contextlib.suppress(BlockingIOError, OSError, ValueError):
            os.write(self._wake_w, b"k")

    def _raw_events(self) -> list[ExecEvent]:
        out: list[ExecEvent] = []
        if self._closed is not None:
            return out
        ring = self.shared.events
        while True:
            rec = ring.get()
            if rec is None:
                break
            out.append(decode_event(rec))
        if self.died is not None and not self._died_reported:
            self._died_reported = True
            out.append(ExecEvent(ExecEventKind.DIED, -1, -1, 0, self.clock.now(), detail=self.died))
        return out

    def events_waiting(self) -> bool:
        """The event ring's head past its tail (``Ring.pending``: a record announced, whole
        or not yet, the same test as the first of
        :meth:`~motorctl.motion.executors.process.rings.Ring.get`, on the same cells), or the
        child's death not reported yet. The tail is this side's, written only under the
        engine lock the caller holds; the head is one aligned 8-byte cell the child writes
        with one store (rings.py): this look loads it once, as ``get`` would, so a record it
        misses is one ``get`` would have missed too."""
        if self._closed is not None:
            return False
        return self.shared.events.pending() or (self.died is not None and not self._died_reported)

    def service(self, now: float) -> float:
        """Top-ups of every motor, then one wake-up byte (a syscall) for all of them."""
        self._batching = True
        try:
            for m, pending in enumerate(self.pending):
                if pending:
                    self._push(m, [])
            return super().service(now)
        finally:
            self._batching = False
            if self._kick_owed:
                self._kick()

    # -- snapshots -------------------------------------------------------------------------
    def position(self, motor: int) -> int:
        if self._closed is not None:
            return self._closed[0][motor]
        return int(self.shared.positions[motor])

    def endstop_active(self, motor: int, direction: int) -> bool:
        if self._closed is not None:
            return False
        line = self.shared.endmap[2 * motor + (1 if direction > 0 else 0)]
        return line >= 0 and bool(self.shared.levels[line])

    def health(self) -> ExecutorHealth:
        if self._closed is not None:
            return ExecutorHealth(
                False,
                self._closed[1]["progress"],
                self.died,
                dict(self._closed[1]),
                self.stats.summary(),
            )
        alive = self.proc is not None and self.proc.poll() is None and self.died is None
        counters = self._counters()
        return ExecutorHealth(
            alive=alive,
            progress=counters["progress"],
            reason=self.died,
            counters=counters,
            latency=self.stats.summary(),
        )

    def _counters(self) -> dict[str, int]:
        """The step core's counters and the rings' retry counts, from the shared block."""
        counters = dict(zip(COUNTER_NAMES, self.shared.counters, strict=True))
        counters.update(self.shared.ring_retries())
        return counters

    def step_lateness(self) -> LatencyStats:
        return self.stats  # after close: a plain copy of the last cells
