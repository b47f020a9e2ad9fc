"""dSPIN chips (issue 34, item 7): what a command costs on a chip that runs its own ramp,
what watching an idle chain costs on its SPI bus, and how fast a fault reaches the host
with and without the chips' FLAG line.

Two daemons run in this process at once (``Daemon.build``, each with its link serving a
real PTY on a thread, the engine's, the planner's and the driver poller's threads on the
real clock, as tests/support/inprocess.py's LiveDaemon), on the mock backend: motor 0 is an
L6470 of a chain of two mock chips (hal/backends/mock/dspin_chip.py, byte for byte behind
py-spidev's API), motor 1 a step/dir motor (its step executor in a process of its own, the
default), motor 2 the chain's other chip (an L6480). Daemon ``flag`` has the chain's FLAG
line and each chip's BUSY line wired (``[motors.dspin] flag``/``busy``, the mock's lines
the chip models drive), daemon ``poll`` has neither. The host is pyserial on the PTY
(motorctl's Client).

1. **MoveTo round trip**: the host's time from writing a MoveTo to reading its answer, on
   motor 0 (the dSPIN: SetParam MAX_SPEED, ACC, DEC and GoTo_DIR over SPI before the
   answer) and on motor 1 (step/dir) in the same run, alternated, each from rest (IsReady
   until ready between runs), on daemon ``poll``; and the chain's SPI transfers between
   writing each dSPIN MoveTo and reading its answer (the mock's count; a poll of the driver
   poller that falls in between adds its 3).
2. **SPI transfers per second while idle**: each daemon's chain transfers (the mock's
   transfer log) over ``--idle-s`` seconds with every motor at rest: the driver poller's
   GetStatus and the chip-ramp executor's reads at ``ramp_idle_poll_ms``; issue 34 allows
   at most 1000 per chain. (tests/hal/layers/dspin/test_layer_lines.py asserts the same
   budget on a virtual clock.)
3. **Fault to E4**: a random wait of 0..``--spread-ms``, an OCD injected into motor 2's chip
   (under the bus's lock, as a chip's flag changes between two transfers), then IsReady(2)
   every ``--interval-ms`` until E4: the time from the injection to that answer. Then the
   fault is taken away and a hard StopMove repeated until it is taken. Both daemons' runs
   interleaved in a shuffled order, so each sees the same machine.

The daemons and the host share one Python interpreter (the GIL): a figure includes the
time a thread waits for another's bytecode, alike for both daemons. The interpreter's
switch interval is the daemon's (``[step_thread] switch_interval_us``, which motorctld sets
for its process, ``prepare_process``) unless ``--switch-interval-us`` says another: at
Python's default of 5 ms a thread woken by the host's bytes, or the host itself, waits up
to that long while another runs Python. The process's CPU time over the idle window is
printed (both daemons and the idle host: one process), with the machine's load average.
``--json FILE`` writes the figures (flat keys).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import random
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.driver_fault import quantile, seconds_to_e4  # noqa: E402
from motorctl.client.client import Client, DeviceError  # noqa: E402
from motorctl.daemon.config import parse_config  # noqa: E402
from motorctl.hal.backends.mock.dspin_chain import DspinChain  # noqa: E402
from motorctl.hal.backends.mock.dspin_chip import DspinChip  # noqa: E402
from motorctl.hal.layers.dspin.driver import DspinDriver  # noqa: E402
from tests.support.daemon_proc import TEST_STEP_THREAD  # noqa: E402
from tests.support.inprocess import LiveDaemon  # noqa: E402

LINES = 'flag = "GPIO25"\n  busy = "{busy}"\n'


def config(wired: bool, poll_ms: float) -> str:
    def lines(busy: str) -> str:
        return "  " + LINES.format(busy=busy) if wired else ""

    return (
        "[step_thread]\n"
        + "".join(f"{k} = {v}\n" for k, v in TEST_STEP_THREAD.items())
        + f"[drivers]\npoll_ms = {poll_ms}\n"
        + '[[motors]]\nname = "dspin"\n  [motors.dspin]\n  driver = "l6470"\n'
        + '  spi = "/dev/spidev0.0"\n  microsteps = 16\n'
        + lines("GPIO24")
        + '[[motors]]\nname = "stepdir"\n'
        + '[[motors]]\nname = "dspin2"\n  [motors.dspin]\n  driver = "l6480"\n'
        + '  spi = "/dev/spidev0.0"\n  position = 1\n  microsteps = 16\n'
        + lines("GPIO23")
    )


#: a run that sees no E4 within this long is a failure of the daemon, not a figure
GIVE_UP_S = 5.0
#: a move of 200 steps that has not ended within this long (a loaded machine) is a failure
REST_S = 30.0


@dataclass
class Subject:
    """One daemon: its PTY's host, its chain, the chip a fault is injected into."""

    name: str
    live: LiveDaemon
    client: Client
    chain: DspinChain
    chip: DspinChip
    driver: DspinDriver
    faults: list[float] = field(default_factory=list)


def start(name: str, wired: bool, tmp: Path, poll_ms: float) -> Subject:
    (tmp / name).mkdir()
    live = LiveDaemon(tmp / name, config(wired, poll_ms), motion=True)
    nodes = live.world.spi_nodes
    assert nodes is not None
    chain = nodes.chains[(0, 0)]
    driver = live.daemon.hw.steppers[2].driver
    assert isinstance(driver, DspinDriver)
    client = Client(live.name, timeout=5.0)
    return Subject(name, live, client, chain.chain, chain.members[1].chip, driver)


def until(what: str, cond: Callable[[], bool], give_up_s: float = GIVE_UP_S) -> None:
    end = time.monotonic() + give_up_s
    while not cond():
        if time.monotonic() > end:
            raise RuntimeError(f"not within {give_up_s} s: {what}")
        time.sleep(0.002)


def ready(client: Client, motor: int) -> Callable[[], bool]:
    return lambda: client.is_ready(motor)


def round_trips(
    s: Subject, runs: int, rng: random.Random
) -> tuple[dict[int, list[float]], list[int]]:
    """MoveTo on motor 0 (dSPIN) and motor 1 (step/dir), alternated in a shuffled order;
    the round trips, and the chain's transfers during each dSPIN MoveTo's (the driver
    poller's GetStatus of the chain, 3 transfers, included when it came in between)."""
    out: dict[int, list[float]] = {0: [], 1: []}
    transfers: list[int] = []
    target = {0: 0, 1: 0}
    for _ in range(runs):
        order = [0, 1]
        rng.shuffle(order)
        for motor in order:
            target[motor] = 100 if target[motor] <= 0 else -100
            before = s.chain.count
            t0 = time.perf_counter()
            s.client.move_to(motor, target[motor], speed=100, acc=100, dec=100)
            out[motor].append(time.perf_counter() - t0)
            if motor == 0:
                transfers.append(s.chain.count - before)
            until(f"motor {motor} at rest", ready(s.client, motor), REST_S)
    return out, transfers


def idle_transfers(subjects: list[Subject], seconds: float) -> dict[str, float]:
    """Each daemon's chain transfers per second over one window, every motor at rest, and
    the process's CPU time over it (``cpu_percent``, of one CPU: both daemons)."""
    before = {s.name: s.chain.count for s in subjects}
    t0, cpu0 = time.monotonic(), time.process_time()
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    out = {s.name: (s.chain.count - before[s.name]) / elapsed for s in subjects}
    out["cpu_percent"] = (time.process_time() - cpu0) / elapsed * 100
    return out


def inject(s: Subject, present: bool) -> None:
    with s.driver.chain.bus.session():  # between two transfers, as a real chip's flag
        s.chip.inject("OCD", present)


def one_fault(s: Subject, interval_s: float) -> float:
    """An OCD on motor 2's chip, IsReady(2) until E4; the seconds in between."""
    inject(s, True)
    t0 = time.monotonic()
    try:
        return seconds_to_e4(s.client, 2, s.name, t0, interval_s)
    finally:
        inject(s, False)
        end = time.monotonic() + GIVE_UP_S
        while True:
            try:
                s.client.stop(2, hard=True)
                break
            except DeviceError:
                if time.monotonic() > end:
                    raise RuntimeError("the fault did not clear") from None
                time.sleep(0.002)


def stats(prefix: str, seconds: list[float]) -> dict[str, float]:
    ms = [x * 1e3 for x in seconds]
    return {
        f"{prefix}_p50_ms": round(quantile(ms, 0.5), 3),
        f"{prefix}_p90_ms": round(quantile(ms, 0.9), 3),
        f"{prefix}_p99_ms": round(quantile(ms, 0.99), 3),
        f"{prefix}_mean_ms": round(sum(ms) / len(ms), 3) if ms else 0.0,
        f"{prefix}_max_ms": round(max(ms), 3) if ms else 0.0,
    }


def measure(args: argparse.Namespace) -> dict[str, Any]:
    rng = random.Random(args.seed)
    tmp = Path(tempfile.mkdtemp(prefix="motorctl-dspin-"))
    subjects: list[Subject] = []
    fig: dict[str, Any] = {"poll_ms": args.poll_ms, "loadavg_start": list(os.getloadavg())}
    interval_us = args.switch_interval_us
    if interval_us is None:  # as motorctld sets it for its process
        interval_us = parse_config(
            config(True, args.poll_ms), "bench"
        ).step_thread.switch_interval_us
    sys.setswitchinterval(interval_us / 1e6)
    fig["switch_interval_us"] = interval_us
    try:
        subjects = [start("poll", False, tmp, args.poll_ms), start("flag", True, tmp, args.poll_ms)]
        time.sleep(0.5)  # imports, first polls
        trips, transfers = round_trips(subjects[0], args.moves, rng)
        fig.update(stats("moveto_dspin", trips[0]))
        fig.update(stats("moveto_stepdir", trips[1]))
        fig["moveto_dspin_transfers_p50"] = quantile([float(n) for n in transfers], 0.5)
        fig["moveto_dspin_transfers_min"] = min(transfers, default=0)
        fig["moveto_dspin_transfers_max"] = max(transfers, default=0)
        fig["moves"] = args.moves
        time.sleep(0.2)
        idle = idle_transfers(subjects, args.idle_s)
        fig["idle_cpu_percent"] = round(idle.pop("cpu_percent"), 2)
        for name, rate in idle.items():
            fig[f"idle_transfers_per_s_{name}"] = round(rate, 1)
        for s in subjects:  # one run each, not counted
            one_fault(s, args.interval_ms / 1e3)
        for _ in range(args.runs):
            order = list(subjects)
            rng.shuffle(order)
            for s in order:
                time.sleep(rng.uniform(0.0, args.spread_ms / 1e3))
                s.faults.append(one_fault(s, args.interval_ms / 1e3))
        fig["runs"] = args.runs
        for s in subjects:
            fig.update(stats(f"fault_{s.name}", s.faults))
        fig["alerts_flag"] = sum(e.alerts for e in subjects[1].live.daemon.hw.poller.entries)
    finally:
        for s in subjects:
            with contextlib.suppress(Exception):
                s.client.close()
            s.live.close()
            s.live.daemon.hw.close()
        fig["loadavg_end"] = list(os.getloadavg())
        fig["threads_left"] = threading.active_count()
    return fig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--moves", type=int, default=100, help="MoveTo runs per motor")
    ap.add_argument("--runs", type=int, default=100, help="fault runs per daemon")
    ap.add_argument("--poll-ms", type=float, default=20.0, help="[drivers] poll_ms of both")
    ap.add_argument("--interval-ms", type=float, default=1.0, help="between the host's IsReady")
    ap.add_argument("--spread-ms", type=float, default=50.0, help="random wait before a fault")
    ap.add_argument("--idle-s", type=float, default=5.0, help="the idle window")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--switch-interval-us",
        type=float,
        help="the interpreter's switch interval (default: the daemon's, as motorctld sets it)",
    )
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON (flat keys)")
    ap.add_argument("--log", action="store_true", help="the daemons' journal on stderr")
    args = ap.parse_args()
    if not args.log:  # each fault run logs its E4 answers and the refused StopMoves
        logging.disable(logging.CRITICAL)
    fig = measure(args)
    la = (
        f"load average {[round(x, 2) for x in fig['loadavg_start']]} -> "
        f"{[round(x, 2) for x in fig['loadavg_end']]}"
    )
    print(
        f"dSPIN on the mock's chip models, [drivers] poll_ms = {args.poll_ms}, switch "
        f"interval {fig['switch_interval_us']} us, {la}"
    )

    def line(prefix: str) -> str:
        return (
            f"p50 {fig[prefix + '_p50_ms']} ms, p90 {fig[prefix + '_p90_ms']} ms, p99 "
            f"{fig[prefix + '_p99_ms']} ms, mean {fig[prefix + '_mean_ms']} ms, max "
            f"{fig[prefix + '_max_ms']} ms"
        )

    print(f"MoveTo round trip, {fig['moves']} each, same run:")
    print(f"  dSPIN motor:    {line('moveto_dspin')}")
    print(f"  step/dir motor: {line('moveto_stepdir')}")
    print(
        f"  SPI transfers on the chain during a dSPIN MoveTo: min "
        f"{fig['moveto_dspin_transfers_min']}, p50 {fig['moveto_dspin_transfers_p50']}, max "
        f"{fig['moveto_dspin_transfers_max']}"
    )
    print(f"SPI transfers per second on the chain of 2, all at rest ({args.idle_s} s):")
    print(f"  without FLAG/BUSY: {fig['idle_transfers_per_s_poll']}")
    print(f"  with FLAG/BUSY:    {fig['idle_transfers_per_s_flag']}")
    print(f"  the process's CPU (both daemons): {fig['idle_cpu_percent']} % of one CPU")
    print(f"fault (OCD) to E4, IsReady every {args.interval_ms} ms, {fig['runs']} runs each:")
    print(f"  STATUS poll only: {line('fault_poll')}")
    print(f"  FLAG line:        {line('fault_flag')} ({fig['alerts_flag']} FLAG edges)")
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
