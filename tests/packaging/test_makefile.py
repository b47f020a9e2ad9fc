"""The Makefile's test-deps, run: what ``make test`` installs from Debian and how it says so.

The recipe runs as written (make, /bin/sh) with a PATH of stand-ins: ``id`` says root or not,
``apt-get`` records what it was asked and prints apt's kind of progress, ``socat``,
``tshark``, ``mergecap``, ``dtc``, ``promtool`` are there or not. So nothing is installed, and what
make would install is seen: socat, tshark and dtc when missing, each announced in one line with
apt's output kept out of the log unless it fails; never Debian's prometheus server package
(promtool comes with it: issue 32), whatever is missing.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from tests.support import REPO

MAKE = shutil.which("make")
pytestmark = pytest.mark.skipif(MAKE is None, reason="make is not installed")

#: the commands the recipe uses besides the stand-ins, taken from this machine
REAL = ("mktemp", "tail", "rm", "cat")

APT_GET = """#!/bin/sh
echo "$*" >> "$FAKE_APT_CALLS"
echo "Reading package lists... Done"
echo "Building dependency tree... Done"
if [ "$FAKE_APT_FAILS" = 1 ] && [ "$1" = install ]; then
  echo "E: Unable to locate package $*"
  exit 100
fi
"""


def run_test_deps(
    tmp: Path, root: bool, have: tuple[str, ...], apt_fails: bool = False
) -> tuple[subprocess.CompletedProcess[str], list[str]]:
    """``make test-deps`` with stand-ins for root (or not) and the tools in ``have``; its run
    and the apt-get calls it made."""
    assert MAKE is not None
    bin_ = tmp / "bin"
    bin_.mkdir()
    scripts = {
        "id": f"#!/bin/sh\necho {0 if root else 1000}\n",
        "apt-get": APT_GET,
        "debconf-set-selections": "#!/bin/sh\ncat > /dev/null\n",
    }
    scripts |= {tool: "#!/bin/sh\nexit 0\n" for tool in have}
    for name, text in scripts.items():
        (bin_ / name).write_text(text)
        (bin_ / name).chmod(0o755)
    for name in REAL:
        real = shutil.which(name)
        assert real is not None, name
        (bin_ / name).symlink_to(real)
    calls = tmp / "apt-calls"
    env = {
        "PATH": str(bin_),
        "HOME": str(tmp),
        "FAKE_APT_CALLS": str(calls),
        "FAKE_APT_FAILS": "1" if apt_fails else "0",
    }
    run = subprocess.run(
        [MAKE, "--no-print-directory", "-f", str(REPO / "Makefile"), "test-deps"],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    return run, calls.read_text().splitlines() if calls.exists() else []


def installs(calls: list[str]) -> list[str]:
    return [call for call in calls if call.split()[:1] == ["install"]]


def test_as_root_it_installs_only_socat_tshark_and_dtc_one_line_each(tmp_path: Path) -> None:
    run, calls = run_test_deps(tmp_path, root=True, have=())
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.splitlines() == [
        "make: installing socat with apt-get (as root: the serial device reconnect tests need it)",
        "make: installing tshark with apt-get (as root: the Wireshark dissector's tests need it)",
        "make: installing dtc with apt-get (as root: the SPI0 overlay's test compiles it)",
    ]
    assert run.stderr == ""  # apt's progress is not in the log
    assert [call.split()[-1] for call in installs(calls)] == [
        "socat",
        "tshark",
        "device-tree-compiler",
    ]
    assert not any("prometheus" in call for call in calls)


def test_as_root_without_promtool_nothing_is_installed_for_it(tmp_path: Path) -> None:
    run, calls = run_test_deps(tmp_path, root=True, have=("socat", "tshark", "mergecap", "dtc"))
    assert run.returncode == 0, run.stdout + run.stderr
    assert calls == [] and run.stdout == "" and run.stderr == ""


def test_a_failed_install_shows_apts_output_and_what_is_skipped(tmp_path: Path) -> None:
    run, calls = run_test_deps(
        tmp_path, root=True, have=("tshark", "mergecap", "dtc"), apt_fails=True
    )
    assert run.returncode == 0, run.stdout + run.stderr  # the tests skip, saying so
    assert [call.split()[-1] for call in installs(calls)] == ["socat"]
    assert "E: Unable to locate package" in run.stderr
    assert "socat could not be installed: the serial device reconnect tests are SKIPPED" in (
        run.stderr
    )


def test_not_root_it_names_the_command_and_installs_nothing(tmp_path: Path) -> None:
    run, calls = run_test_deps(tmp_path, root=False, have=())
    assert run.returncode == 0 and calls == [] and run.stdout == ""
    assert "run 'sudo apt-get install socat'" in run.stderr
    assert "run 'sudo apt-get install tshark'" in run.stderr
    assert "run 'sudo apt-get install device-tree-compiler'" in run.stderr
    assert "prometheus" not in run.stderr


def pytest_line(target: str) -> str:
    """The pytest command of ``make TARGET``'s recipe (``make -n``: printed, not run)."""
    assert MAKE is not None
    run = subprocess.run(
        [MAKE, "-n", "--no-print-directory", "-f", str(REPO / "Makefile"), target],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    (line,) = [line for line in run.stdout.splitlines() if "/pytest " in line]
    return line


def test_what_make_test_leaves_out_make_test_slow_runs_and_ci_runs_both() -> None:
    """pyproject.toml's addopts leave the tests marked slow out of every plain pytest run
    (make test's too); make test-slow runs exactly those, and .ci/run runs both parts, so a
    test marked slow still runs in CI."""
    ini = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "-m 'not slow'" in ini["addopts"]
    assert " -m " not in pytest_line("test")
    assert pytest_line("test-slow").endswith(" -m slow")
    parts = re.findall(r"^\s*timed (make [\w-]+)", (REPO / ".ci" / "run").read_text(), re.M)
    assert parts[:3] == ["make test", "make test-slow", "make test-dspin"], parts
