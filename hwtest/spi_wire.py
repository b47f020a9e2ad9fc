"""The TMC driver's bytes on a real kernel SPI bus (run in the gpio-sim guest with GSIM_SPI=1).

spi-gpio bit-bangs /dev/spidev1.0 over gpio-sim bank 0 lines 0..3 (SCK, MOSI, MISO, CS); the
kernel's gpio:gpio_value trace events record every edge. This script drives motorctl's own
SPI code (py-spidev from the guest's venv, the HAL's bus ``motorctl.hal.spi``, the TMC
layer's SPI link and driver) and decodes the trace: each datagram must be one chip-select
window of exactly 40 clocks, SCK must idle high (SPI mode 3) and the MOSI bits sampled on
SCK's rising edges must be the datagrams the driver means to send. MISO has no chip behind
it (it reads the sim's pull), so the driver must also say that no chip answers, naming the
device.

Usage (guest): python3 hwtest/spi_wire.py; exit status 0 when every check passed.
"""

from __future__ import annotations

import glob
import re
import sys
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.dont_write_bytecode = True

from motorctl.hal.layers.tmc.driver import TmcDriver  # noqa: E402
from motorctl.hal.layers.tmc.fields import Reg  # noqa: E402
from motorctl.hal.layers.tmc.link import TmcError, TmcLink  # noqa: E402
from motorctl.hal.layers.tmc.settings import TmcSettings  # noqa: E402
from motorctl.hal.layers.tmc.tmc2130 import TMC2130  # noqa: E402
from motorctl.hal.spi import SpiAddress, SpiBuses, SpiSettings, spidev_factory  # noqa: E402

SCK, MOSI, MISO, CS = 0, 1, 2, 3
TRACE = "/sys/kernel/tracing"
SIM = "/sys/devices/platform/gpio-sim.0/gpiochip0"
EVENT = re.compile(r"(\d+\.\d+): gpio_value: (\d+) (get|set) (\d+)")


def put(name: str, value: object) -> None:
    Path(TRACE, name).write_text(str(value))


def pull_miso(level: str) -> None:
    Path(SIM, f"sim_gpio{MISO}", "pull").write_text(level)


def base() -> int:
    for line in Path("/sys/kernel/debug/gpio").read_text().splitlines():
        m = re.match(r"gpiochip0: GPIOs (\d+)-", line)
        if m:
            return int(m.group(1))
    raise LookupError("gpiochip0 not in /sys/kernel/debug/gpio")


def traced(action: Callable[[], object]) -> tuple[list[tuple[int, str, int]], object]:
    """Run ``action`` with gpio_value tracing on; (events of lines 0..3, what it returned)."""
    put("tracing_on", 0)
    put("trace_clock", "mono")
    for ev in glob.glob(f"{TRACE}/events/gpio/*/enable"):
        Path(ev).write_text("0")
    put("events/gpio/gpio_value/enable", 1)
    put("trace", "")
    put("tracing_on", 1)
    try:
        result: object = action()
    except Exception as exc:  # the result to check, not a failure of the script
        result = exc
    put("tracing_on", 0)
    lost = sum(
        int(v)
        for st in glob.glob(f"{TRACE}/per_cpu/cpu*/stats")
        for k, _, v in (ln.partition(":") for ln in Path(st).read_text().splitlines())
        if k.strip() == "overrun"
    )
    assert lost == 0, f"the trace lost {lost} events"
    b = base()
    events = [
        (int(m.group(2)) - b, m.group(3), int(m.group(4)))
        for m in map(EVENT.search, Path(TRACE, "trace").read_text().splitlines())
        if m
    ]
    return [e for e in events if 0 <= e[0] <= 3], result


def datagrams(events: list[tuple[int, str, int]]) -> tuple[list[bytes], list[int], list[int]]:
    """(MOSI bytes per chip-select window, clock edges per window, SCK level at each CS fall)."""
    level: dict[int, int] = {}
    frames: list[list[int]] = []
    rising: list[int] = []
    idle: list[int] = []
    for line, op, value in events:
        if op != "set":
            continue
        before = level.get(line)
        level[line] = value
        if line == CS and value == 0 and before != 0:
            frames.append([])
            rising.append(0)
            idle.append(level.get(SCK, -1))
        elif line == SCK and level.get(CS) == 0 and before == 0 and value == 1:
            frames[-1].append(level[MOSI])  # mode 3 samples on the rising edge
            rising[-1] += 1
    out = [
        bytes(int("".join(map(str, bits[i : i + 8])), 2) for i in range(0, len(bits), 8))
        for bits in frames
    ]
    return out, rising, idle


def check(name: str, ok: bool, detail: str) -> bool:
    print(f"{'ok  ' if ok else 'FAIL'} {name}: {detail}")
    return ok


def main() -> int:
    buses = SpiBuses()
    factory = spidev_factory()
    dev = buses.bus(SpiAddress(1, 0), SpiSettings(500_000), "spi_wire", factory)
    good = True

    # 1. start-up against a bus with no chip: MISO pulled high reads 0xffffffff
    pull_miso("pull-up")
    driver = TmcDriver("x", dev, TmcSettings(chip=TMC2130))
    events, result = traced(driver.start)
    frames, clocks, idle = datagrams(events)
    good &= check(
        "no chip answers",
        isinstance(result, TmcError)
        and "/dev/spidev1.0: no driver chip answers (IOIN reads 0xffffffff)" in str(result),
        str(result),
    )
    good &= check(
        "IOIN read = two datagrams",
        frames == [bytes([Reg.IOIN, 0, 0, 0, 0])] * 2,
        " ".join(f.hex() for f in frames),
    )
    good &= check(
        "40 clocks per datagram, SCK idle high (mode 3)",
        clocks == [40, 40] and idle == [1, 1],
        f"clocks {clocks}, SCK at CS {idle}",
    )

    # 2. a verified write: the datagram, then the echo read; MISO low echoes zeros
    pull_miso("pull-down")
    dev.open()
    link = TmcLink(dev, TMC2130)
    value = 0x140300C3
    events, result = traced(lambda: link.write(Reg.CHOPCONF, value))
    frames, clocks, idle = datagrams(events)
    write = bytes([0x80 | Reg.CHOPCONF]) + value.to_bytes(4, "big")
    expect = [write, bytes([Reg.IOIN, 0, 0, 0, 0])]
    good &= check(
        "write datagram and echo read on the wire",
        frames == expect,
        " ".join(f.hex() for f in frames),
    )
    good &= check(
        "the missing echo is caught",
        isinstance(result, TmcError)
        and "did not receive CHOPCONF = 0x140300c3 intact (it echoed 0x00000000)" in str(result),
        str(result),
    )
    good &= check("40 clocks per datagram", clocks == [40, 40], str(clocks))

    # 3. a pipelined multi-register read: n + 1 datagrams, the last address repeated
    events, result = traced(lambda: link.read_many([Reg.GCONF, Reg.DRV_STATUS, Reg.TSTEP]))
    frames, _, _ = datagrams(events)
    addrs = [f[0] for f in frames]
    good &= check(
        "pipelined read order",
        addrs == [0x00, 0x6F, 0x12, 0x12] and all(f[1:] == b"\0\0\0\0" for f in frames),
        str([hex(a) for a in addrs]),
    )
    good &= check("values as MISO gave them", result == [0, 0, 0], str(result))
    dev.close()
    print("PASS spi_wire" if good else "FAIL spi_wire")
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
