"""The Raspberry Pi example config, unchanged, on the GPIO chips of real boards (gpio-sim in
the VM, `hwtest/run layouts`): a Pi 4, and a Pi 5 as three generations of kernels number its
chips (hwtest/boards.py). On each the daemon steps a motor (every STEP rise counted in the
kernel's trace on the header chip, whatever its number), homes on an end stop pressed through
the sim and drives and reads pins; `--probe` names the chip by label and the board's layout;
a config that names a chip or line that is not there gets the chips that are, listed.

The guest boots without chips of its own (GSIM_BANKS=none); each test makes its board's
chips and removes them again. Only run by `hwtest/run layouts` (in its guests a skip fails).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hwtest import boards, gsim
from hwtest.boards import BOARDS, Board
from hwtest.layout import GUEST_READY_TIMEOUT_S, MOTORS, PINS, example_in_the_guest
from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.interfaces import MonotonicClock
from motorctl.hal.registry import probe_hardware
from tests.support.daemon_proc import DaemonProcess, run_probe

pytestmark = pytest.mark.skipif(
    not boards.available() or os.environ.get("GSIM_LAYOUTS") != "1",
    reason="needs gpio-sim without chips of its own (hwtest/run layouts)",
)
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")


@pytest.fixture(params=BOARDS, ids=[b.key for b in BOARDS])
def board(request: pytest.FixtureRequest) -> Iterator[Board]:
    b: Board = request.param
    with boards.built(b):
        yield b


def header_line(b: Board, name: str) -> tuple[str, int]:
    """(gpiochipN, offset) of a header line such as GPIO17 or ID_SDA on this board."""
    chip = b.chip(b.header)
    return f"gpiochip{chip.number}", chip.names.index(name)


def level(b: Board, name: str) -> bool:
    chip, offset = header_line(b, name)
    return gsim.sim_value(offset, chip)


def pull(b: Board, name: str, high: bool) -> None:
    chip, offset = header_line(b, name)
    gsim.sim_pull(offset, high, chip)


def probe(tmp_path: Path, text: str) -> tuple[int, str]:
    """``motorctld --probe`` as a user runs it: exit status and report."""
    cfg = tmp_path / "probe.toml"
    cfg.write_text(text)
    out = run_probe(cfg)
    assert "Traceback" not in out.stdout + out.stderr, out.stdout + out.stderr
    return out.returncode, out.stdout


def probe_here(text: str) -> tuple[int, str]:
    """The same report made in this process (what --probe prints, without starting Python
    again, which costs seconds in the emulated guest): exit status 1 when it has problems."""
    report = probe_hardware(
        "gpiod", hardware_spec(parse_config(text, "layout.toml")), MonotonicClock()
    )
    return (1 if report.problems else 0), report.text()


def chips_listed(b: Board) -> str:
    return "chips: " + ", ".join(
        f"gpiochip{c.number} [{c.label}] {len(c.names)} lines"
        for c in sorted(b.chips, key=lambda c: c.number)
    )


def test_the_example_runs_unchanged(board: Board, tmp_path: Path) -> None:
    b = board
    header = f"gpiochip{b.chip(b.header).number}"
    text = example_in_the_guest(API)
    for m in MOTORS:
        pull(b, m[3], True)  # end stops clear (active low)

    # --probe: the layout by name, every line on the header chip, named by its label
    rc, out = probe(tmp_path, text)
    assert rc == 0, out
    assert f"board layout:\n  {b.layout}\n" in out, out
    for use, name, offset in (("motors[0].step", "GPIO17", 17), ("pins.6", "ID_SDA", 0)):
        assert f"{use:<22} {name:<16} -> {header}:{offset} '{name}' [{b.header}]" in out, out
    used = b.chip(b.header)
    assert f"chips the config uses:\n  {header} [{b.header}] {len(used.names)} lines\n" in out
    for link, target in b.links.items():
        assert f"{target} [" in out and f"/dev/{link} links to it" in out, out

    # the daemon: steps, an end stop, pins
    (tmp_path / "d").mkdir()
    d = DaemonProcess(tmp_path / "d", text, ready_timeout=GUEST_READY_TIMEOUT_S).start()
    try:
        with d.client(timeout=20.0) as c:
            step = gsim.chip_base(header) + 17
            start = c.position(0)
            gsim.trace_start()
            c.move_to(0, start + 200)
            c.wait_moved(0, 60_000)
            gsim.trace_stop()
            rises = [e for e in gsim.sets(gsim.trace_read(), step) if e.value == 1]
            assert gsim.trace_lost() == 0
            assert c.position(0) == start + 200
            assert len(rises) == 200, f"{len(rises)} STEP rises on {header}:17 for 200 steps"

            # motor 1 homes onto its end stop (GPIO16), pressed through the sim
            home_start = c.position(1)
            c.init_move(1, False, speed=0)
            deadline = time.monotonic() + 30
            while home_start - c.position(1) < 50:
                assert time.monotonic() < deadline, "motor 1 did not start homing"
                time.sleep(0.01)
            pull(b, MOTORS[1][3], False)  # pressed (active low)
            # homing stops on the switch, backs off (DIR high) while it stays pressed and
            # zeroes where it releases (PROTOCOL.md, InitMove)
            deadline = time.monotonic() + 30
            while not level(b, MOTORS[1][1]):
                assert time.monotonic() < deadline, "motor 1 did not back off the end stop"
                time.sleep(0.01)
            backing = c.position(1)
            while c.position(1) - backing < 3:
                assert time.monotonic() < deadline, "motor 1 did not step off the end stop"
                time.sleep(0.01)
            assert not c.is_ready(1), "homing ended with the end stop still pressed"
            pull(b, MOTORS[1][3], True)  # released
            c.wait_moved(1, 60_000)
            homed = c.position(1)
            assert 0 <= homed <= 40, f"homing zeroed {homed} steps from where it released"

            # pins: outputs on the header chip follow SetPin, inputs read the outside
            for n in range(4):
                for high in (True, False):
                    c.set_pin(n, high)
                    assert level(b, PINS[n]) is high, f"pin {n} ({PINS[n]}) {high}"
            for n in range(4, 8):
                for high in (True, False):
                    pull(b, PINS[n], high)
                    assert c.get_pin(n) is high, f"pin {n} ({PINS[n]}) reads {high}"
    finally:
        d.close()


#: per board, a config mistake of its users and what the daemon must say
MISTAKES = {
    # a Pi 5 config (by number) on a Pi 4
    "pi4": (
        "gpiochip4:17",
        "motors[0].step: no GPIO chip 'gpiochip4' ({chips}); chip numbers change between "
        "kernels (a Raspberry Pi 5's RP1 was gpiochip4 before 6.6.45, gpiochip0 after): write "
        "the chip's label (pinctrl-bcm2711:17) or the line's name",
    ),
    # GPIO0 as a pin-out drawing calls it: the kernel names lines 0 and 1 ID_SDA and ID_SCL
    "pi5-gpiochip4": (
        "GPIO0",
        "motors[0].step: no GPIO line named 'GPIO0' on any chip ({chips}); `gpioinfo` lists "
        "the names, or write chip:offset",
    ),
    # an old config after the kernel update that moved the RP1
    "pi5-2026": (
        "gpiochip4:17",
        "motors[0].step: no GPIO chip 'gpiochip4' ({chips}); chip numbers change between "
        "kernels (a Raspberry Pi 5's RP1 was gpiochip4 before 6.6.45, gpiochip0 after): write "
        "the chip's label (pinctrl-rp1:17) or the line's name",
    ),
}


def test_a_chip_or_line_that_is_not_there_lists_the_chips(board: Board) -> None:
    b = board
    text = example_in_the_guest(API)
    if b.key in MISTAKES:
        wrong, message = MISTAKES[b.key]
        rc, out = probe_here(text.replace('step = "GPIO17"', f'step = "{wrong}"'))
        assert rc == 1, out
        assert f"PROBLEM: {message.format(chips=chips_listed(b))}" in out, out
    else:
        # Raspberry Pi OS's link /dev/gpiochip4 -> gpiochip0: an old config still finds
        # the RP1, and the line through the link is known for the line of that name
        assert b.links == {"gpiochip4": "gpiochip0"}
        rc, out = probe_here(text.replace('step = "GPIO17"', 'step = "gpiochip4:17"'))
        assert rc == 0, out
        assert "gpiochip4:17     -> gpiochip0:17 'GPIO17' [pinctrl-rp1]" in out, out
        rc, out = probe_here(text.replace('dir = "GPIO27"', 'dir = "gpiochip4:17"'))
        assert rc == 1, out
        assert (
            "PROBLEM: motors[0].dir and motors[0].step are the same line "
            "(gpiochip0:17 'GPIO17'); each line can have one use"
        ) in out, out
    # the chip by its label works on every board, whatever its number
    label_ref = f"{b.header}:17"
    rc, out = probe_here(text.replace('step = "GPIO17"', f'step = "{label_ref}"'))
    assert rc == 0, out
    header = f"gpiochip{b.chip(b.header).number}"
    assert f"{label_ref:<16} -> {header}:17 'GPIO17' [{b.header}]" in out, out
