"""motorctld end to end on a real kernel GPIO chip (gpio-sim), inside the VM (hwtest/run).

The daemon runs from this checkout with docs/examples/raspberry-pi.toml (the Pi's line names
are gpio-sim's too); the client talks to it over a PTY; the test looks at the lines from
the outside: gpio-sim's sysfs for levels and pulls, the kernel's gpio_value trace for
every level the daemon set, in order, with CLOCK_MONOTONIC timestamps.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwtest import gsim
from hwtest.layout import (
    DC,
    EXAMPLE,
    GUEST_READY_TIMEOUT_S,
    MOTORS,
    PINS,
    example_in_the_guest,
    where,
)
from motorctl.client.client import Client
from tests.support.daemon_proc import DaemonProcess, run_probe

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")

REPO = Path(__file__).resolve().parent.parent
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")


def example_config() -> str:
    return example_in_the_guest(API)


def gpio(line: str) -> int:
    chip, off = where(line)
    return gsim.chip_base(chip) + off


def level(line: str) -> bool:
    chip, off = where(line)
    return gsim.sim_value(off, chip)


def pull(line: str, high: bool) -> None:
    chip, off = where(line)
    gsim.sim_pull(off, high, chip)


def wait_for(what: str, cond: object, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def end_stops_clear() -> None:
    for m in MOTORS:
        pull(m[3], True)  # active low: high = clear


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    end_stops_clear()
    d = DaemonProcess(
        tmp_path_factory.mktemp("d"), example_config(), ready_timeout=GUEST_READY_TIMEOUT_S
    ).start()
    try:
        yield d
    finally:
        d.close()


@pytest.fixture
def client(daemon: DaemonProcess) -> Iterator[Client]:
    with daemon.client(timeout=10.0) as c:
        yield c


def test_daemon_runs_the_example_with_the_chosen_api(daemon: DaemonProcess) -> None:
    assert "gpiod hardware; step core compiled;" in daemon.ready_line
    if API != "auto":
        assert f"gpiod {API}" in daemon.stderr()
    assert daemon.status()["executor"]["core"] == "compiled"  # the default, where built
    assert "step core: compiled (its lines: GPIO character devices)" in daemon.stderr()
    # the dataclasses' compiled methods for the guest's Python were there (hwtest/run writes
    # them for the trixie root's 3.13): a start without them warns and compiles each again
    warned = [line for line in daemon.stderr().splitlines() if "dataclass code:" in line]
    assert warned == [], warned


def test_every_pin_command_end_to_end(client: Client) -> None:
    outputs, inputs = range(0, 4), range(4, 8)
    # initial levels from [[pins]]: pin 1 starts high, the other outputs low
    assert [level(PINS[n]) for n in outputs] == [False, True, False, False]
    for n in outputs:
        for high in (True, False, True):
            client.set_pin(n, high)
            assert level(PINS[n]) is high, f"SetPin {n} {high}"
            assert client.get_pin(n) is high
    for n in inputs:
        for high in (True, False):
            pull(PINS[n], high)
            assert client.get_pin(n) is high, f"GetPin {n} with the outside at {high}"
    # ConfigPin: output 2 becomes an input (follows the outside), then an output again
    client.config_pin(2, False)
    for high in (False, True):
        pull(PINS[2], high)
        assert client.get_pin(2) is high
    client.config_pin(2, True)
    client.set_pin(2, False)
    assert level(PINS[2]) is False
    # ConfigPin: input 7 becomes an output
    client.config_pin(7, True)
    client.set_pin(7, True)
    assert level(PINS[7]) is True
    client.config_pin(7, False)


def test_step_pulses_in_the_trace_equal_the_position(client: Client) -> None:
    step, dir_ = gpio(MOTORS[0][0]), gpio(MOTORS[0][1])
    start = client.position(0)
    gsim.trace_start()
    client.move_to(0, start + 300)
    client.wait_moved(0, 30_000)
    up_pos = client.position(0)
    client.move_to(0, start + 120)
    client.wait_moved(0, 30_000)
    gsim.trace_stop()
    events = gsim.trace_read()
    assert gsim.trace_lost() == 0
    assert up_pos == start + 300
    assert client.position(0) == start + 120
    steps = gsim.changes(gsim.sets(events, step))
    rises = [e for e in steps if e.value == 1]
    assert len(rises) == 300 + 180
    assert len([e for e in gsim.sets(events, step) if e.value == 1]) == 480  # no double sets
    # DIR: high for the 300 up, low for the 180 down, set before the first step each way
    dirs = gsim.changes(gsim.sets(events, dir_))
    assert dirs[-1].value == 0
    setup = 20e-6  # dir_setup_us of the example
    down = [e for e in dirs if e.value == 0 and e.ts > rises[0].ts]
    assert len(down) == 1, dirs
    assert down[0].ts > rises[299].ts
    assert rises[300].ts - down[0].ts >= setup * 0.99
    ups = [e for e in dirs if e.value == 1]
    if ups:  # set high inside the trace: before the first step, by the set-up time
        assert rises[0].ts - ups[-1].ts >= setup * 0.99
    else:  # already high from an earlier move
        assert level(MOTORS[0][1]) is False
    assert len([e for e in rises if e.ts < down[0].ts]) == 300


def test_end_stop_raised_by_the_sim_stops_homing_and_zero_is_where_it_releases(
    client: Client,
) -> None:
    motor, endstop = 1, MOTORS[1][3]
    step, dir_ = gpio(MOTORS[1][0]), gpio(MOTORS[1][1])
    pull(endstop, True)
    start = client.position(motor)
    gsim.trace_start()
    client.init_move(motor, False, speed=0)
    wait_for("100 homing steps", lambda: start - client.position(motor) >= 100)
    trigger = time.monotonic()
    pull(endstop, False)  # pressed: active low
    # stopped at the trigger, homing backs off (DIR up: high) at second_speed (250 step/s)
    # while the switch stays pressed, and goes on until it is released
    wait_for("the back-off", lambda: level(MOTORS[1][1]) is True)
    backing = client.position(motor)
    wait_for("5 back-off steps", lambda: client.position(motor) - backing >= 5)
    assert not client.is_ready(motor)  # still on the switch: still homing
    release = time.monotonic()
    pull(endstop, True)
    client.wait_moved(motor, 30_000)
    gsim.trace_stop()
    events = gsim.trace_read()
    rises = [e for e in gsim.sets(events, step) if e.value == 1]
    up = [e.ts for e in gsim.changes(gsim.sets(events, dir_)) if e.value == 1 and e.ts > trigger]
    seek = [e for e in rises if trigger < e.ts < up[0]]
    # The step thread sees the kernel's edge event at its next step and stops once the
    # debounce (0.5 ms) has passed. On v2 the kernel debounces too, with a timer of jiffy
    # resolution (4 ms at HZ=250), and under TCG on a loaded host the guest's clock runs in
    # bursts: measured 1-14 steps, up to 45 ms. Without the end stop the run would go on for
    # max_travel (250000 steps).
    late = seek[-1].ts - trigger if seek else 0.0
    print(f"homing: {len(seek)} steps in {late * 1000:.2f} ms after the trigger")
    assert len(seek) <= 40 and late <= 0.2, (
        f"{len(seek)} steps, the last {late * 1000:.2f} ms after the trigger"
    )
    # The release the same way, at 250 step/s (4 ms a step): zero is the first step that
    # saw it released, and the steps made until the debounce had passed count from there
    off = [e for e in rises if e.ts > release]
    print(f"homing: {len(off)} back-off steps after the release")
    assert off and len(off) <= 12 and off[-1].ts - release <= 0.2
    homed = client.position(motor)
    assert 0 <= homed < len(off)  # homed: zero where the switch released
    client.move_to(motor, 300)
    client.wait_moved(motor, 30_000)
    client.move_to(motor, 0)  # a host's first program after homing: back to zero
    client.wait_moved(motor, 30_000)
    assert client.position(motor) == 0


def test_dc_bridge_levels_through_a_run_and_its_end_state(client: Client) -> None:
    in1, in2, en = (gpio(x) for x in DC)

    def state() -> tuple[bool, bool, bool]:
        return level(DC[0]), level(DC[1]), level(DC[2])

    assert state() == (False, False, False)  # coasting at start
    gsim.trace_start()
    client.dc_move(True, 300, hiz=False)
    assert state() == (True, False, True)  # forward
    wait_for("brake at the end of the run", lambda: state() == (True, True, True), 10.0)
    client.dc_move(False, 200, hiz=True)
    assert state() == (False, True, True)  # reverse
    wait_for("coast at the end of the run", lambda: state() == (False, False, False), 10.0)
    # a reversal while running passes through coast for the dead time (50 ms)
    client.dc_move(True, 5000, hiz=False)
    client.dc_move(False, 300, hiz=False)
    wait_for("brake after the reversed run", lambda: state() == (True, True, True), 10.0)
    gsim.trace_stop()
    ev = gsim.trace_read()
    s1, s2 = gsim.changes(gsim.sets(ev, in1)), gsim.changes(gsim.sets(ev, in2))
    # IN1: fwd 1, brake (stays 1), 0 for reverse, ..., 1 for the last forward run, 0 (coast
    # for the dead time), stays 0 in reverse, 1 for the final brake
    assert [e.value for e in s1][-3:] == [1, 0, 1]
    _fwd, coast, brake = s1[-3:]
    rev = [e for e in s2 if e.value == 1 and coast.ts < e.ts < brake.ts]
    assert len(rev) == 1, s2
    assert rev[0].ts - coast.ts >= 0.050 * 0.99, f"dead time {rev[0].ts - coast.ts:.4f} s"
    assert [e.value for e in gsim.changes(gsim.sets(ev, en))][-1] == 1


def test_probe_shows_lines_consumers_and_end_stops(daemon: DaemonProcess) -> None:
    # the running daemon holds every line: --probe must say by whom and fail
    cfg = daemon.config
    assert cfg is not None
    out = run_probe(cfg)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "held by 'motorctl'" in out.stdout
    assert (
        "PROBLEM: motors[0].step: line gpiochip0:17 'GPIO17' is already in use by 'motorctl'"
        in out.stdout
    )


def test_probe_on_free_lines_reads_end_stops_and_moves_nothing(
    tmp_path: Path, daemon: DaemonProcess
) -> None:
    daemon.close()  # after the module's other tests: the lines are free again
    cfg = tmp_path / "pi.toml"
    # gpio-sim models a requested pull-up as the outside level, so z's end stop is requested
    # as-is here to let the test hold it pressed while the probe opens it
    z = 'endstop_min = "GPIO20"\n  endstop_min_bias = "pull-up"'
    assert z in example_config()
    text = example_config().replace(z, 'endstop_min = "GPIO20"')
    cfg.write_text(text)
    end_stops_clear()
    pull(MOTORS[2][3], False)  # z's end stop pressed
    gsim.trace_start()
    out = run_probe(cfg)
    gsim.trace_stop()
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"libgpiod Python API {API}" in out.stdout or API == "auto"
    assert "gpiochip0 [sim-bank0] 32 lines" in out.stdout
    assert "motors[2] min: level 0 (TRIGGERED)" in out.stdout
    assert "motors[0] min: level 1 (clear)" in out.stdout
    steps = [e for m in MOTORS for e in gsim.sets(gsim.trace_read(), gpio(m[0])) if e.value]
    assert steps == [], "the probe stepped a motor"
    pull(MOTORS[2][3], True)


def test_a_line_held_by_another_consumer_is_a_clear_error(tmp_path: Path) -> None:
    """Another program holds z's STEP line: the daemon refuses to start and names it."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, *map(str, where(MOTORS[2][0]))],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        assert holder.stdout is not None
        assert holder.stdout.readline().strip() == "holding"
        d = DaemonProcess(tmp_path, example_config(), ready_timeout=GUEST_READY_TIMEOUT_S)
        with pytest.raises(RuntimeError) as err:
            d.start()
        d.kill()
        message = str(err.value)
        assert (
            "motors[2].step: line gpiochip0:5 'GPIO5' is already in use by 'intruder'" in message
        ), message
        assert "Traceback" not in message
    finally:
        holder.kill()
        holder.wait(10)


HOLD = """
import sys
from motorctl.hal.backends.gpiod.chip import LineSettings, load_api
from motorctl.hal.backends.gpiod.wiring import LineRef
api = load_api()
(line,) = api.resolve([("held", LineRef(chip=sys.argv[1], offset=int(sys.argv[2])))])
req = api.request("intruder", [(line, LineSettings(output=True))])
print("holding", flush=True)
import time
time.sleep(3600)
"""


def test_shutdown_leaves_outputs_at_their_safe_values(tmp_path: Path) -> None:
    """SIGTERM: the last level the daemon set on every pin output is its safe value, the
    bridge brakes; pins set the other way first."""
    end_stops_clear()
    d = DaemonProcess(tmp_path, example_config(), ready_timeout=GUEST_READY_TIMEOUT_S).start()
    try:
        with d.client(timeout=10.0) as c:
            c.set_pin(0, True)  # safe = false
            c.set_pin(1, False)  # safe = true
            c.set_pin(2, True)
            c.dc_move(True, 60_000, hiz=True)
            assert level(DC[0]) is True
        gsim.trace_start()
        assert d.terminate() == 0
    finally:
        d.close()
    gsim.trace_stop()
    ev = gsim.trace_read()
    last = {n: gsim.changes(gsim.sets(ev, gpio(PINS[n])))[-1].value for n in (0, 1, 2)}
    assert last == {0: 0, 1: 1, 2: 0}
    in1, in2 = (gsim.changes(gsim.sets(ev, gpio(x)))[-1].value for x in DC[:2])
    assert (in1, in2) == (1, 1), "the DC motor was not braked at shutdown"


def test_probe_of_the_full_example_adds_the_spi_drivers_through_the_hook(tmp_path: Path) -> None:
    """With its [motors.tmc] tables the example's probe also asks the TMC layer (registry
    LAYERS): the guest has no /dev/spidev0.x, which is a named problem, the GPIO part stays."""
    cfg = tmp_path / "pi.toml"
    cfg.write_text(EXAMPLE.read_text().replace('api = "auto"', f'api = "{API}"'))
    end_stops_clear()
    out = run_probe(cfg)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "configured lines (before opening)" in out.stdout
    assert "all 20 lines requested as 'motorctl' and released; nothing moved" in out.stdout
    problems = [ln for ln in out.stdout.splitlines() if ln.startswith("PROBLEM:")]
    assert problems and all("spidev" in p for p in problems), out.stdout
    assert "Traceback" not in out.stdout + out.stderr
