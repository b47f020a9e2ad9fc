"""A stand-in for the py-spidev module in a motorctld subprocess
(tests/hal/layers/tmc/test_layer_e2e.py).

Put this folder first on PYTHONPATH and describe the chips in MOTORCTL_FAKE_SPI (JSON):
``{"chips": {"0.0": "tmc2130", "0.1": "tmc5160:step_dir", "0.2": "tmc5160"}, "control":
"/path/control.json"}`` (a TMC5160's SD_MODE is low, ramp generator on, unless ":step_dir").
Before each transfer the control file, when it changed, sets each chip's injected state:
``{"0.0": {"faults": [25], "step_rate": 0.0, "stall": false, "ref_l_at": -500}}``. The chips are the
register-level models of tests/support/tmc_model.py behind the same fake py-spidev API.
"""

from __future__ import annotations

import json
import os
from typing import Any

from motorctl.hal.interfaces import MonotonicClock
from tests.support.tmc_model import FakeKernel, FakeSpiDev, TmcModel

_config: dict[str, Any] = json.loads(os.environ.get("MOTORCTL_FAKE_SPI", '{"chips": {}}'))
_kernel = FakeKernel()
for _key, _kind in _config["chips"].items():
    _bus, _cs = (int(x) for x in _key.split("."))
    # a TMC5160's ramp generator runs on the real clock (SD_MODE low unless "...:step_dir")
    _chip, _, _mode = _kind.partition(":")
    _kernel.chips[(_bus, _cs)] = TmcModel(
        _chip, clock=MonotonicClock(), sd_mode=int(_mode == "step_dir")
    )
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
        chip.ref_l_at = state.get("ref_l_at")
        chip.ref_r_at = state.get("ref_r_at")


class SpiDev(FakeSpiDev):
    def __init__(self) -> None:
        super().__init__(_kernel)

    def xfer2(self, values: list[int]) -> list[int]:
        _apply_control()
        return super().xfer2(values)
