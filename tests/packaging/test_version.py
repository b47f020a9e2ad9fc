"""`motorctl --version` and `motorctld --version` print motorctl.__version__."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

import motorctl
from motorctl.client import cli
from motorctl.daemon.start import launch
from motorctl.daemon.start import main as daemon_main

ENTRIES = [("motorctl", cli.main), ("motorctld", launch.main), ("motorctld", daemon_main.main)]


@pytest.mark.parametrize(("name", "entry"), ENTRIES)
def test_version_option(name: str, entry: object, capsys: pytest.CaptureFixture[str]) -> None:
    assert callable(entry)
    with pytest.raises(SystemExit) as info:
        entry(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out == f"{name} {motorctl.__version__}\n"


def test_version_is_a_release_number_and_the_installed_one() -> None:
    assert re.fullmatch(r"\d+\.\d+\.\d+", motorctl.__version__)
    out = subprocess.run(
        [sys.executable, "-c", "import importlib.metadata as m; print(m.version('motorctl'))"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert out.stdout.strip() == motorctl.__version__
