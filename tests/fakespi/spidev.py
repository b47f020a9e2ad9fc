"""A stand-in for the py-spidev module in a motorctld subprocess (tests/test_tmc_e2e.py).

Put this folder first on PYTHONPATH and describe the chips in MOTORCTL_FAKE_SPI (JSON):
``{"chips": {"0.0": "tmc2130", ...}, "control": "/path/control.json"}``. Before each
transfer the control file, when it changed, sets each chip's injected state:
``{"0.0": {"faults": [25], "step_rate": 0.0, "stall": false}}``. The chips are the
register-level models of tests/tmc_model.py behind the same fake py-spidev API.
"""

from __future__ import annotations

import json
import os
from typing import Any

from tests.tmc_model import FakeKernel, FakeSpiDev, TmcModel

_config: dict[str, Any] = json.loads(os.environ.get("MOTORCTL_FAKE_SPI", '{"chips": {}}'))
_kernel = FakeKernel()
for _key, _kind in _config["chips"].items():
    _bus, _cs = (int(x) for x in _key.split("."))
    _kernel.chips[(_bus, _cs)] = TmcModel(_kind)
_control: str | None = _config.get("control")
_seen = [0.0]


def _apply_control() -> None:
    if _control is None or not os.path.exists(_control):
        return
    mtime = os.stat(_control).st_mtime
    if mtime == _seen[0]:
        return
    _seen[0] = mtime
    with open(_control) as f:
        wanted = json.load(f)
    for key, state in wanted.items():
        bus, cs = (int(x) for x in key.split("."))
        chip = _kernel.chips[(bus, cs)]
        chip.faults = set(state.get("faults", []))
        chip.step_rate = float(state.get("step_rate", 0.0))
        chip.stall = bool(state.get("stall", False))


class SpiDev(FakeSpiDev):
    def __init__(self) -> None:
        super().__init__(_kernel)

    def xfer2(self, values: list[int]) -> list[int]:
        _apply_control()
        return super().xfer2(values)
