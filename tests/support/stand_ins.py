"""The environment of a motorctld process that imports stand-ins instead of the hardware
libraries: tests/fakegpiod/ (a libgpiod v2 binding that refuses every line request) and
tests/fakespi/ (py-spidev over the register-level chip models of tmc_model.py)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from motorctl.client.client import Client, DeviceError
from motorctl.protocol.codec import ErrorCode
from tests.support import REPO

#: the folders to put first on PYTHONPATH, by the module they stand in for
FOLDERS = {"gpiod": REPO / "tests" / "fakegpiod", "spidev": REPO / "tests" / "fakespi"}


def stand_in_env(
    *modules: str, chips: dict[str, str], control: Path | None = None
) -> dict[str, str]:
    """PYTHONPATH with the stand-ins of ``modules`` ("gpiod", "spidev") first, and the fake
    SPI's chips (``{"0.0": "tmc5160", ...}``) and control file (chip state set while the
    daemon runs)."""
    paths = [str(FOLDERS[m]) for m in modules] + [os.environ.get("PYTHONPATH", "")]
    spi: dict[str, object] = {"chips": chips}
    if control is not None:
        spi["control"] = str(control)
    return {
        "PYTHONPATH": os.pathsep.join(p for p in paths if p),
        "MOTORCTL_FAKE_SPI": json.dumps(spi),
    }


def set_chips(control: Path, state: dict[str, dict[str, object]]) -> None:
    """Tell the fake SPI's chip models their new state (``{"0.0": {"faults": [25]}}``):
    written beside the control file and renamed into place, since the daemon's driver poll
    reads it whenever it changes (a write in place could be read half done, as an empty
    file: a JSON error in the stand-in library, not the fault asked for)."""
    part = control.with_suffix(".part")
    part.write_text(json.dumps(state))
    os.replace(part, control)


def until_e4(c: Client, motor: int, target: int, timeout_ms: int) -> None:
    """After a driver fault was set: moves of ``motor`` to ``target`` (at SPEED 250) until
    one is refused or stopped with E4, within 10 s (the driver poll's news)."""
    deadline = time.monotonic() + 10.0
    while True:  # a move either is refused (E4) or is stopped by the fault (E4)
        try:
            c.move_to(motor, target, speed=250)
            c.wait_moved(motor, timeout_ms=timeout_ms)
        except DeviceError as exc:
            assert exc.code is ErrorCode.MOTOR_ERROR
            return
        assert time.monotonic() < deadline, "no E4 within 10 s of the fault"


def until_cleared(c: Client, motor: int) -> None:
    """After the driver fault was cleared: a hard StopMove of ``motor`` until it is taken
    (E4 while the fault is latched), within 10 s."""
    deadline = time.monotonic() + 10.0
    while True:
        try:
            c.stop(motor, hard=True)
            return
        except DeviceError:
            assert time.monotonic() < deadline, "the fault did not clear within 10 s"
            time.sleep(0.05)
