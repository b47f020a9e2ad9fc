"""The gpiod backend (backend.py) where no GPIO chip is needed: without libgpiod's binding
it says what to install (opening and ``--probe``), and it offers a compiled core only its
own lines. Its lines themselves run on gpio-sim in the hardware tier (hwtest/)."""

from __future__ import annotations

import importlib.util

import pytest

from motorctl.daemon.config import parse_config
from motorctl.daemon.start.assemble import hardware_spec
from motorctl.hal.backends.gpiod.backend import GpiodBackend
from motorctl.hal.backends.mock.world import mock_axis
from motorctl.hal.contract import ProblemKind
from motorctl.hal.interfaces import HalError, MonotonicClock
from motorctl.hal.registry import open_hardware, probe_hardware
from motorctl.hal.spec import HardwareSpec
from tests.support import REPO
from tests.support.daemon_proc import run_probe
from tests.support.mock_factory import MockFactory

EXAMPLE = REPO / "docs" / "examples" / "raspberry-pi.toml"


@pytest.mark.skipif(
    importlib.util.find_spec("gpiod") is not None, reason="libgpiod's binding is installed here"
)
def test_without_libgpiod_the_backend_says_what_to_install() -> None:
    spec = hardware_spec(parse_config(EXAMPLE.read_text(), str(EXAMPLE)))
    with pytest.raises(HalError, match=r"pip install gpiod.*apt install python3-libgpiod"):
        open_hardware("gpiod", spec, MonotonicClock())
    report = probe_hardware("gpiod", spec, MonotonicClock())
    problem = report.problems[0]  # then the TMC layer's: no py-spidev either
    assert problem.kind is ProblemKind.DEVICE and "python3-libgpiod" in problem.text
    out = run_probe(EXAMPLE)
    assert out.returncode == 1
    assert "PROBLEM: the gpiod backend needs libgpiod's Python binding" in out.stdout
    assert "Traceback" not in out.stdout + out.stderr


def test_it_offers_a_compiled_core_its_own_lines_only(mock_factory: MockFactory) -> None:
    io = mock_factory.step_io(HardwareSpec((mock_axis(),)))
    assert GpiodBackend().compiled_lines(io) == "not the gpiod backend's step IO"
