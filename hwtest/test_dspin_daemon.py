"""The Raspberry Pi example's dSPIN variant on a real spidev, inside the gpio-sim guest.

The example's three motors are moved by a daisy chain of dSPIN chips on /dev/spidev0.0 (an
L6470, an L6480, a powerSTEP01, as docs/examples/dspin.toml chains them) instead of STEP/DIR
lines and TMC5160s; its DC motor and pins stay on gpio-sim's lines (both libgpiod APIs, as
the tier runs them). The spidev is the kernel's: spi-sim.c's user bus (GSIM_SPI=user),
whose transfers hwtest/dspin_chain.py answers with the mock backend's register-level chip
models, so the daemon's py-spidev calls go through spidev's ioctls and the SPI core as on a
Pi. Checked: the daemon starts on the chain (each chip identified by CONFIG's reset value,
set up and read back), MoveTo moves each chip, InitMove homes on the SW
input (zero where ReleaseSW leaves the switch), an overcurrent on one chip gives E4 with
the flag named, and the whole byte transcript, decoded per chip, is the datasheets'
framing (mode 3, one byte per chip per transfer, chip select raised after each) carrying
the commands the daemon was asked for. Each chip's FLAG and BUSY outputs are gpio-sim
lines the responder drives (``[motors.dspin] flag``/``busy``, the lines the variant's
dropped STEP and DIR leave free): the overcurrent reaches E4 through the FLAG line's edge
(the chip's ``flag_alerts`` in the status), and a motor at rest is answered from its BUSY
line (``busy_answers`` grows while the transcript shows no read of that chip over SPI but
one in REST_READ_EVERY; the line falls while the chip runs). In the v2 guest, ``motorctld
--probe`` then finds each chip over the same spidev.
"""

from __future__ import annotations

import json
import os
import re
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hwtest import gsim
from hwtest.layout import GUEST_READY_TIMEOUT_S, in_the_guest, where
from motorctl.hal.dspin.chips import L6470, L6480, POWERSTEP01_VOLTAGE, Chip
from motorctl.hal.dspin.commands import Command, Op, decode
from motorctl.hal.layers.dspin.driver import REST_READ_EVERY
from tests.support.daemon_proc import DaemonProcess, run_probe
from tests.support.stand_ins import until_cleared, until_e4

pytestmark = pytest.mark.skipif(not gsim.available(), reason="needs gpio-sim (make test-hw)")

REPO = Path(__file__).resolve().parent.parent
EXAMPLE = REPO / "docs" / "examples" / "raspberry-pi.toml"
API = os.environ.get("MOTORCTL_GPIOD_API", "auto")
CHIPS: tuple[Chip, ...] = (L6470, L6480, POWERSTEP01_VOLTAGE)
DRIVERS = ("l6470", "l6480", "powerstep01")
#: each chip's SW closes at or below this shaft position (microsteps from power-up)
SWITCH_AT = -400
#: each chip's FLAG and BUSY line: the STEP and DIR lines of its motor in the example
FLAG = ("GPIO17", "GPIO22", "GPIO5")
BUSY = ("GPIO27", "GPIO23", "GPIO6")
#: the idle reads the BUSY check waits for (the executor's at rest: [dspin] ramp_idle_poll_ms)
IDLE_READS = 12
#: the tables of each motor that wire it to STEP/DIR lines and a TMC5160
_STEP_DIR = re.compile(
    r"  \[motors\.endstop\]\n(?:  \w+ = [^\n]*\n)*"
    r"  \[motors\.gpiod\]\n(?:  \w+ = [^\n]*\n)*"
    r"  \[motors\.tmc\][^\n]*\n(?:  \w+ = [^\n]*\n)*"
)


#: the variant's polls: each transfer is a round trip to a Python process under TCG
POLLS = """[drivers]
poll_ms = 100.0

[dspin]
ramp_poll_ms = 50.0
ramp_idle_poll_ms = 250.0

[dc]
"""


def dspin_variant() -> str:
    """docs/examples/raspberry-pi.toml as the guest runs it (:func:`in_the_guest`), each
    motor's end stop, STEP/DIR lines and TMC5160 replaced by its chip of one dSPIN chain on
    /dev/spidev0.0 (SW: the end stop below the axis; FLAG and BUSY on the lines STEP and DIR
    leave free); the polls slowed for the emulated guest, where each transfer is a round
    trip to a Python process."""
    text = in_the_guest(EXAMPLE.read_text(), API)
    text = text.replace('  source = "endstop"\n', "")
    tables = iter(
        f"""  [motors.dspin]
  driver = "{driver}"
  spi = "/dev/spidev0.0"
  position = {i}
  microsteps = 16
  ocd_th = 8
  switch = "min"
  flag = "{FLAG[i]}"
  busy = "{BUSY[i]}"
"""
        for i, driver in enumerate(DRIVERS)
    )
    text, n = _STEP_DIR.subn(lambda _: next(tables), text)
    assert n == 3, "the example's motor tables changed"
    text = text.replace("[dc]\n", POLLS)
    assert not re.search(r"^\s*\[motors\.(tmc|gpiod)\]", text, re.M) and "[drivers]" in text
    return text


@dataclass
class Chain:
    """The responder (hwtest/dspin_chain.py) and its files."""

    proc: subprocess.Popen[str]
    control: Path
    transcript: Path

    def inject(self, faults: dict[int, list[str]]) -> None:
        part = self.control.with_suffix(".part")
        part.write_text(json.dumps({str(k): v for k, v in faults.items()}))
        os.replace(part, self.control)

    def stop(self) -> list[dict[str, Any]]:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=60)
        assert self.proc.returncode == 0, f"the chain's responder exited {self.proc.returncode}"
        return [json.loads(line) for line in self.transcript.read_text().splitlines()]


def start_chain(tmp: Path) -> Chain:
    control, transcript = tmp / "control.json", tmp / "transcript.jsonl"
    cmd = [sys.executable, str(REPO / "hwtest" / "dspin_chain.py"), "--control", str(control)]
    cmd += ["--transcript", str(transcript), "--switch-at", str(SWITCH_AT)]
    for option, lines in (("--flag", FLAG), ("--busy", BUSY)):
        cmd += [option, ",".join("{}:{}".format(*where(line)) for line in lines)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 120.0)
    line = proc.stdout.readline() if ready else ""
    if line != "ready\n":
        proc.kill()
        proc.wait()
        raise AssertionError(
            f"the chain's responder did not open /dev/spi-sim ({line!r}): is spi-sim loaded "
            "with user=1 (GSIM_SPI=user)?"
        )
    return Chain(proc, control, transcript)


@dataclass(frozen=True)
class Seen:
    """One command as one chip read it: the transfers it came in (their seq), and for
    GetParam/GetStatus the bytes the chip sent back after it."""

    seq: tuple[int, ...]
    command: Command
    answer: bytes


def per_chip(transfers: list[dict[str, Any]], chip: int) -> list[Seen]:
    """Chip ``chip``'s byte stream out of the transcript, parsed as the chip parses it:
    byte ``len - 1 - chip`` of each transfer (docs/dspin.md "On the wire")."""
    slot = len(CHIPS) - 1 - chip
    seen: list[Seen] = []
    i = 0
    while i < len(transfers):
        t = transfers[i]
        d = decode(CHIPS[chip], bytes.fromhex(t["tx"])[slot])
        assert not d.wrong, f"transfer {t['seq']}: chip {chip} gets a byte it has no command for"
        n = d.follows
        part = transfers[i + 1 : i + 1 + n]
        tx = bytes(bytes.fromhex(x["tx"])[slot] for x in part)
        rx = bytes(bytes.fromhex(x["rx"])[slot] for x in part)
        reads = d.op in (Op.GET_PARAM, Op.GET_STATUS)
        if reads:
            assert tx == bytes(len(tx)), f"transfer {t['seq']}: NOPs must clock an answer out"
        seen.append(
            Seen(
                tuple(x["seq"] for x in [t, *part]),
                d.command(b"" if reads else tx),
                rx if reads else b"",
            )
        )
        i += 1 + n
    return seen


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[DaemonProcess, Chain]]:
    tmp = tmp_path_factory.mktemp("dspin")
    config = tmp / "pi-dspin.toml"
    config.write_text(dspin_variant())
    t0 = time.monotonic()
    chain = start_chain(tmp)
    print(f"chain ready, s: {time.monotonic() - t0:.1f}")
    try:
        d = DaemonProcess(tmp, config.read_text(), ready_timeout=GUEST_READY_TIMEOUT_S).start()
        print(f"daemon ready, s: {time.monotonic() - t0:.1f}")
        try:
            yield d, chain
        finally:
            d.close()
    finally:
        if chain.proc.poll() is None:
            chain.proc.kill()
            chain.proc.wait()


def test_the_example_runs_its_motors_on_a_dspin_chain_over_spidev(
    rig: tuple[DaemonProcess, Chain],
) -> None:
    d, chain = rig
    t0 = time.monotonic()
    assert "gpiod hardware" in d.ready_line
    drivers = d.status()["drivers"]
    assert [(x["chip"], x["device"], x["chain_position"]) for x in drivers] == [
        ("L6470", "/dev/spidev0.0", 0),
        ("L6480", "/dev/spidev0.0", 1),
        ("powerSTEP01 (voltage mode)", "/dev/spidev0.0", 2),
    ]
    assert all(x["polls"] > 0 and x["spi_errors"] == 0 for x in drivers)
    wired = [(x["flag_line"], x["busy_line"], x["flag_alerts"]) for x in drivers]
    assert wired == [(f, b, 0) for f, b in zip(FLAG, BUSY, strict=True)]
    assert all(high(line) for line in FLAG + BUSY), "a chip signals at rest (the lines read low)"
    with d.client(timeout=30.0) as c:  # an answer under TCG on a busy machine: seconds
        print(f"status read, s: {time.monotonic() - t0:.1f}")
        c.move_to(0, 320, speed=250)  # MoveTo: GoTo_DIR on chip 0 (x)
        print(f"moveto answered, s: {time.monotonic() - t0:.1f}")
        c.move_to(2, 160, speed=250)  # and on chip 2 (z), meanwhile
        c.wait_moved(0, timeout_ms=20_000)
        c.wait_moved(2, timeout_ms=20_000)
        assert (c.position(0), c.position(2)) == (320, 160)
        print(f"moved, s: {time.monotonic() - t0:.1f}")
        c.init_move(0, False, speed=250)  # down to SW (shaft -400), back off: zero there
        c.wait_moved(0, timeout_ms=30_000)
        assert c.position(0) == 0
        c.move_to(0, 80, speed=250)
        c.wait_moved(0, timeout_ms=20_000)
        assert c.position(0) == 80
        print(f"homed, s: {time.monotonic() - t0:.1f}")
        rest = answered_from_busy(d, 2)  # z stands since its move: BUSY answers its reads
        print(f"rested, s: {time.monotonic() - t0:.1f}")
        c.move_to(2, 4160, speed=60)  # 4000 steps at 240 step/s: its BUSY line falls
        until_low(BUSY[2], 20.0)
        c.stop(2, hard=True)
        c.wait_moved(2, timeout_ms=20_000)
        assert high(BUSY[2]), "z stopped: its BUSY line still low"
        before = [x["flag_alerts"] for x in d.status()["drivers"]]
        chain.inject({1: ["OCD"]})  # y's bridges: overcurrent (FLAG falls between transfers)
        until_e4(c, 1, 100, timeout_ms=20_000)
        # the poller took FLAG's falling edge and read the chain at once: E4 came through it
        after = [x["flag_alerts"] for x in d.status()["drivers"]]
        assert after[1] > before[1] and after[::2] == before[::2], (before, after)
        assert [high(line) for line in FLAG] == [True, False, True]  # OCD lasts: y's low
        chain.inject({})
        until_cleared(c, 1)
        c.move_to(1, 100, speed=250)
        c.wait_moved(1, timeout_ms=20_000)
        assert c.position(1) == 100
        assert all(high(line) for line in FLAG + BUSY), "cleared and at rest: every line high"
    assert d.status()["drivers"][1]["fault_counts"].get("OCD", 0) >= 1
    # a MoveTo of until_e4's that reaches the chip after the fault and before the poll reads
    # it is refused by the chip (bridges off: NOTPERF_CMD, the L6480's CMD_ERROR), and the
    # same read names both flags
    named = r"driver fault: L6480: (CMD_ERROR \(the chip refused a command\), )?OCD[;:]"
    assert re.search(named, d.stderr()), "the journal does not name the fault"
    assert d.terminate() == 0
    if API == "v2":  # once, in one guest: another motorctld under TCG costs 40-60 s
        assert d.config is not None
        probe_finds_the_chain(d.config)
        print(f"probed, s: {time.monotonic() - t0:.1f}")
    transfers = chain.stop()
    print(f"{len(transfers)} transfers, s: {time.monotonic() - t0:.1f}")
    check_transcript(transfers)
    check_rest(transfers, 2, *rest)


def probe_finds_the_chain(config: Path) -> None:
    """``motorctld --probe`` over the spidev: each chip's CONFIG read and named, STATUS
    decoded, no problem (the daemon has let go of the lines)."""
    out = run_probe(config)
    assert out.returncode == 0, out.stdout + out.stderr
    for i, (name, chip) in enumerate(zip("xyz", CHIPS, strict=True)):
        said = f"{name}: #{i} on /dev/spidev0.0: configured {chip.name}, CONFIG 0x"
        said += f"{chip.config.reset:04X} ({chip.name}); STATUS "
        assert said in out.stdout, out.stdout


def high(line: str) -> bool:
    """The level of a gpio-sim line as the daemon's request reads it."""
    chip, offset = where(line)
    return gsim.sim_value(offset, chip)


def until_low(line: str, timeout_s: float) -> None:
    """Wait (``timeout_s`` at most) until ``line`` reads low."""
    deadline = time.monotonic() + timeout_s
    while high(line):
        assert time.monotonic() < deadline, f"{line} not low within {timeout_s} s"
        time.sleep(0.05)


def answered_from_busy(d: DaemonProcess, chip: int) -> tuple[float, float, int]:
    """Wait (60 s at most) until ``IDLE_READS`` of the executor's reads of ``chip``, at rest,
    have been answered from its BUSY line: the window (CLOCK_MONOTONIC, as the responder's
    transcript) and how many were answered from the line in it or just after."""
    first = d.status()["drivers"][chip]["busy_answers"]
    start = time.monotonic()
    while True:
        end = time.monotonic()
        answered = d.status()["drivers"][chip]["busy_answers"] - first
        if answered >= IDLE_READS:
            return start, end, answered
        assert end < start + 60.0, f"{answered} reads of chip {chip} answered from BUSY in 60 s"
        time.sleep(0.25)


def check_rest(transfers: list[dict[str, Any]], chip: int, t0: float, t1: float, n: int) -> None:
    """While ``n`` reads of ``chip`` were answered from BUSY (from ``t0`` to just after
    ``t1``), its ramp reads over SPI (GetParam STATUS, ABS_POS, SPEED) were one in
    ``REST_READ_EVERY`` at most: without the line every one of the ``n`` is three GetParams.
    The chain's GetStatus polls ([drivers] poll_ms) address every chip whatever BUSY says."""
    at = {t["seq"]: t["t"] for t in transfers}
    reads = [
        s.command.register
        for s in per_chip(transfers, chip)
        if s.command.op is Op.GET_PARAM and t0 <= at[s.seq[0]] <= t1
    ]
    spi_reads = n // REST_READ_EVERY + 2  # a read at each end of the window
    assert len(reads) <= 3 * spi_reads, f"{len(reads)} GetParams of chip {chip} at rest: {reads}"


def check_transcript(transfers: list[dict[str, Any]]) -> None:
    assert transfers, "no transfer reached the chain"
    for t in transfers:  # the framing: mode 3, 8 bits, one byte per chip, CS up after each
        assert t["error"] is None, t
        assert (t["mode"], t["bits"], len(t["tx"]) // 2, t["cs_off"]) == (3, 8, 3, 1), t
        assert 0 < t["speed_hz"] <= 5_000_000, t
    assert [t["seq"] for t in transfers] == list(range(1, len(transfers) + 1))
    x, y, z = (per_chip(transfers, i) for i in range(3))
    # MoveTo: GoTo_DIR forward to 320 on x, to 160 on z, NOPs to the others in its transfers
    for seen, target, others in ((x, 320, (1, 2)), (z, 160, (0, 1))):
        goto = [s for s in seen if s.command == Command(Op.GO_TO_DIR, dir=1, value=target)]
        assert len(goto) == 1, [s.command for s in seen if s.command.op is Op.GO_TO_DIR]
        for o in others:
            slot = len(CHIPS) - 1 - o
            bytes_o = [bytes.fromhex(transfers[q - 1]["tx"])[slot] for q in goto[0].seq]
            assert bytes_o == [0, 0, 0, 0], f"chip {o} got {bytes_o} during a MoveTo not its own"
    # InitMove: towards the switch (reverse), stopped by SW; ReleaseSW forward, MARK where
    # the switch opened (the zero: ABS_POS runs on, docs/dspin.md); then the move to 80
    # from that zero, the chip's ABS_POS MARK + 80
    moves = [
        s
        for s in x
        if s.command.op in (Op.GO_TO_DIR, Op.GO_UNTIL, Op.RUN, Op.RELEASE_SW)
        or s.command == Command(Op.GET_PARAM, register=L6470.registers["MARK"])
    ]
    release = next(i for i, s in enumerate(moves) if s.command.op is Op.RELEASE_SW)
    down = moves[release - 1].command
    assert down.op in (Op.GO_TO_DIR, Op.GO_UNTIL) and down.dir == 0, down
    assert moves[release].command.dir == 1, moves[release]
    rest = moves[release + 1 :]
    nxt = next(i for i, s in enumerate(rest) if s.command.op is not Op.GET_PARAM)
    assert nxt > 0, f"MARK not read after the release: {rest[:3]}"
    mark_read, after = rest[nxt - 1], rest[nxt].command
    mark = L6470.registers["MARK"].value(int.from_bytes(mark_read.answer, "big"))
    assert SWITCH_AT < mark <= SWITCH_AT + 16, f"MARK {mark}: not where SW opens"
    assert after == Command(Op.GO_TO_DIR, dir=1, value=mark + 80), after

    # the fault: y's GetStatus answers, as the L6480 lays them out, report OCD; x's never
    def faults(chip: int, seen: list[Seen]) -> set[str]:
        words = [int.from_bytes(s.answer, "big") for s in seen if s.command.op is Op.GET_STATUS]
        return {f for w in words for f in CHIPS[chip].status.decode(w).faults}

    assert "OCD" in faults(1, y)
    assert "OCD" not in faults(0, x) | faults(2, z)
