"""Homing end to end (motion/motor.py), against motorctld as a process on a PTY over the mock
world, on each step core: a host's first program after InitMove -- home, move away, MoveTo 0,
WaitMoved, GetAbsPos 0 -- gets no E4, for each homing kind (the end stop, with and without the
second approach; the stall, on an axis without switches) and both directions. Zero is the
first position off the switch: one step further toward it is still an end stop hit (E4).
The same program runs on dSPIN chips (a chain of six mock chips: the switch on each chip's
SW input, the stall from its STEP_LOSS flags), where the chip homes the motor itself."""

from __future__ import annotations

import pytest

from motorctl.client.client import Client, DeviceError
from motorctl.protocol.codec import ErrorCode
from tests.support.daemon_proc import DaemonProcess, StartDaemon

#: make test-dspin runs the dSPIN chips' test here (the STEP/DIR one is marked stepdir)
pytestmark = pytest.mark.conformance

#: (name, [motors.homing] lines, homed by its switch) per kind; each homes both ways
KINDS = (
    ("endstop", "", True),
    ("pull_off", "pull_off = 40\nsecond_speed = 500.0", True),
    ("stall", 'source = "stall"', False),
)
#: the mock's end stops: the switch is active at and beyond them, the hard stop is there
ENDSTOP = 1500


def motors() -> list[tuple[str, int, bool]]:
    """(kind, direction, homed by its switch) of each motor, in config order."""
    return [(name, d, switch) for name, _, switch in KINDS for d in (1, -1)]


#: the dSPIN chips the motors of :func:`config` get with ``dspin``, in chain order
DSPIN_CHIPS = ("l6470", "l6480", "powerstep01")


def dspin_table(chip: int, d: int, switch: bool) -> str:
    """Motor ``chip``'s [motors.dspin] table: a chip of the chain on /dev/spidev0.0, its SW
    input the switch the motor homes towards (none for a stall homing)."""
    sw = ("max" if d > 0 else "min") if switch else "none"
    return f"""  [motors.dspin]
  driver = "{DSPIN_CHIPS[chip % len(DSPIN_CHIPS)]}"
  spi = "/dev/spidev0.0"
  position = {chip}
  microsteps = 16
  switch = "{sw}"
"""


def motor_table(name: str, homing: str = "", switch: bool = True) -> str:
    """One motor over the mock's end stops at -ENDSTOP and ENDSTOP (the switch active at and
    beyond them, the hard stop there; ``switch`` False: the hard stops only); ``homing``:
    its [motors.homing] lines beyond speed and travel."""
    return f"""
[[motors]]
name = "{name}"
default_speed = 6000.0
default_accel = 60000.0
default_decel = 60000.0
  [motors.homing]
  speed = 6000.0
  max_travel = 5000
  {homing}
  [motors.mock]
  endstop_min = -{ENDSTOP}
  endstop_max = {ENDSTOP}
  switches = {"true" if switch else "false"}
"""


def config(dspin: bool = False) -> str:
    """The machine: one motor per homing kind and direction; ``dspin``: each on a chip of
    one chain of dSPIN chips (else STEP/DIR motors)."""
    homing = {name: lines for name, lines, _ in KINDS}
    out = []
    for chip, (name, d, switch) in enumerate(motors()):
        out.append(motor_table(f"{name}_{'up' if d > 0 else 'down'}", homing[name], switch))
        if dspin:
            out.append(dspin_table(chip, d, switch))
    return "".join(out) + "\n[mock]\nwires = []\n"


@pytest.mark.stepdir
@pytest.mark.parametrize("core", ["compiled", "python"])
def test_after_homing_moveto_0_and_back_gives_no_e4(motorctld: StartDaemon, core: str) -> None:
    daemon = motorctld(f'{config()}\n[step_thread]\ncore = "{core}"\n')
    assert daemon.status()["executor"]["core"] == core
    with daemon.client() as c:
        home_away_and_back(c)


def test_after_homing_on_dspin_chips_moveto_0_and_back_gives_no_e4(motorctld: StartDaemon) -> None:
    """The chip ramps every motor (the chip-ramp executor, no step executor): GoUntil and
    ReleaseSW on SW, or a run ended by STEP_LOSS, then GoTo_DIR away and back to 0."""
    daemon = motorctld(config(dspin=True))
    chips = [
        (d["chip"].split()[0].lower(), d["chain_position"]) for d in daemon.status()["drivers"]
    ]
    assert chips == [(DSPIN_CHIPS[i % 3], i) for i in range(len(motors()))]
    with daemon.client() as c:
        home_away_and_back(c)


def home_away_and_back(c: Client) -> None:
    """Home every motor, MoveTo away and back to 0 (no E4), then one step onto the switch
    of each motor homed by one (E4, an end stop hit, cleared by StopMove)."""
    every = list(enumerate(motors()))
    for i, (_, d, _) in every:  # every motor at once, each step for all of them
        c.init_move(i, d > 0)
    wait_all(c, every)
    assert [c.position(i) for i, _ in every] == [0] * len(every)
    for i, (_, d, _) in every:
        c.move_to(i, -d * 800)  # away
    wait_all(c, every)
    for i, _ in every:
        c.move_to(i, 0)  # and back to where it homed
    wait_all(c, every)  # no E4: no switch touched, no stall
    assert [c.position(i) for i, _ in every] == [0] * len(every)
    assert all(c.is_ready(i) for i, _ in every)
    hits = [(i, d) for i, (_, d, switch) in every if switch]
    for i, d in hits:  # one step beyond 0 is on the switch: an end stop hit
        c.move_to(i, d)
    for i, d in hits:
        with pytest.raises(DeviceError) as hit:
            c.wait_moved(i, timeout_ms=10_000)
        assert hit.value.code is ErrorCode.MOTOR_ERROR, f"motor {i}"
        assert c.position(i) == d  # it stopped on the switch
        c.stop(i)  # clears it (the switch is no driver fault)
        c.move_to(i, 0)
        c.wait_moved(i, timeout_ms=10_000)
        assert c.position(i) == 0


def wait_all(c: Client, every: list[tuple[int, tuple[str, int, bool]]]) -> None:
    for i, (kind, d, _) in every:
        try:
            c.wait_moved(i, timeout_ms=10_000)
        except DeviceError as exc:
            raise AssertionError(f"motor {i} ({kind}, {'up' if d > 0 else 'down'}): {exc}") from exc


# ---------------------------------------------------------------- an end stop pressed already

#: one motor with both switches (motor_table); on dSPIN chips: moved by an L6470 whose SW
#: input is the switch below (a dSPIN chip has one)
PRESSED = motor_table("x")


@pytest.mark.stepdir
@pytest.mark.parametrize(
    ("executor", "core"), [("process", "compiled"), ("process", "python"), ("thread", "python")]
)
def test_a_move_into_an_end_stop_pressed_already_takes_no_step(
    motorctld: StartDaemon, executor: str, core: str
) -> None:
    daemon = motorctld(f'{PRESSED}\n[step_thread]\nexecutor = "{executor}"\ncore = "{core}"\n')
    assert daemon.status()["executor"]["core"] == core
    into_the_pressed_stop_and_away(daemon)


def test_a_move_into_a_dspin_switch_closed_already_is_not_sent_to_the_chip(
    motorctld: StartDaemon,
) -> None:
    """The chip's SW stops it only as it closes: the executor keeps the motion from the chip."""
    daemon = motorctld(PRESSED + dspin_table(0, -1, True) + "\n[mock]\nwires = []\n")
    into_the_pressed_stop_and_away(daemon)


def into_the_pressed_stop_and_away(daemon: DaemonProcess) -> None:
    """Move down into the switch below (E4, a hit), StopMove; then three times a Move or a
    MoveTo beyond it: E4 at once, "already active", the position unchanged (no creep); a
    MoveTo away works; back on the switch, InitMove toward it goes straight to the back-off
    and a MoveTo 0 after it gets no E4."""

    def reason() -> str:
        return str(daemon.status()["motors"][0]["last_error"]["reason"])

    with daemon.client() as c:
        c.move(0, False)
        with pytest.raises(DeviceError) as hit:
            c.wait_moved(0, timeout_ms=10_000)
        assert hit.value.code is ErrorCode.MOTOR_ERROR
        on_it = c.position(0)
        assert reason() == f"end stop hit at {on_it} outside homing" and on_it <= -ENDSTOP
        for again in range(3):
            c.stop(0)  # clears it
            if again == 1:
                c.move_to(0, on_it - 1000)
            else:
                c.move(0, False)
            with pytest.raises(DeviceError) as pressed:
                c.wait_moved(0, timeout_ms=10_000)
            assert pressed.value.code is ErrorCode.MOTOR_ERROR
            assert c.position(0) == on_it, f"attempt {again}: a step into the pressed stop"
            assert reason() == f"end stop already active at {on_it} outside homing"
        c.stop(0)
        c.move_to(0, on_it + 500)  # away: how a user backs off
        c.wait_moved(0, timeout_ms=10_000)
        assert c.position(0) == on_it + 500
        c.move(0, False)  # onto the switch again
        with pytest.raises(DeviceError):
            c.wait_moved(0, timeout_ms=10_000)
        c.stop(0)
        c.init_move(0, False)  # homing from the pressed switch: the back-off only
        c.wait_moved(0, timeout_ms=10_000)
        assert 0 <= c.position(0) <= 3  # zero where it released (a chip brakes a little on)
        c.move_to(0, 0)
        c.wait_moved(0, timeout_ms=10_000)  # no E4: 0 is off the switch
        assert c.position(0) == 0
