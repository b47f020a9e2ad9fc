"""The environment of a motorctld process that imports stand-ins instead of the hardware
libraries: tests/fakegpiod/ (a libgpiod v2 binding that refuses every line request) and
tests/fakespi/ (py-spidev over the register-level chip models of tmc_model.py)."""

from __future__ import annotations

import json
import os
from pathlib import Path

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
