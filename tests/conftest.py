"""What every test shares.

The tests mirror the package, one folder a room, each test file named after the module it
tests (``_e2e``: against motorctld as a process on a real PTY):

    protocol/   client/   daemon/   motion/   hal/    the rooms' tests
    contract/   the backend contract (the mock here; gpiod on gpio-sim in hwtest/run)
    docs/       the README's walkthrough run as written; every path the pages name exists
    packaging/  debian/, the wheel, the systemd units, --version, hwtest/run
    support/    the shared rigs, one module each: wait (``until``, the deadline wait),
                frames, rigs (the engine or the step core on a virtual clock), inprocess
                (``LiveDaemon``: an in-process daemon serving a real PTY), daemon_proc
                (``DaemonProcess``), spi_bench and tmc_model (TMC chips on a fake SPI bus),
                stand_ins (the environment for tests/fakegpiod/ and tests/fakespi/), fsutil,
                tamper (a forwarder that changes one answer: the replay's tests)
    deb/        make test-deb's install check; fakegpiod/, fakespi/: stand-in modules

This file is also loaded for tests/contract in the hardware tier's guests: it imports
nothing beyond pytest at module level. Here: the ``motorctld`` fixture (daemons as
processes, stopped after their test), ``step_core`` and ``core_rig`` (a test run on each
step core, Python and compiled), and for every test:

- The root logger is put back after each test. A test that runs motorctld's ``main()`` in
  this process (``--print-default-config``, ``--check-config``) installs the daemon's stderr
  handler; left in place, it printed the INFO lines of later tests' link threads (which may
  log after their test ended) between pytest's dots.
- The processes the tests start (daemons, their step executors, the CLIs) keep their
  compiled bytecode in ``build/pycache`` when the environment says not to write any beside
  the sources (``PYTHONDONTWRITEBYTECODE``): otherwise each daemon start compiled the whole
  package twice (the daemon and its executor process), a tenth of a second of CPU at every
  one of the suite's hundred-odd starts. The bytecode is the same either way.

Daemons started by the tests (tests/support/daemon_proc.py) log into a file of their test, shown
with the test's output when it fails.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from tests.support.daemon_proc import DaemonProcess, StartDaemon
    from tests.support.rigs import StepCoreRig


def pytest_configure(config: pytest.Config) -> None:
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        cache = config.rootpath / "build" / "pycache"
        cache.mkdir(parents=True, exist_ok=True)
        os.environ["PYTHONPYCACHEPREFIX"] = str(cache)
        del os.environ["PYTHONDONTWRITEBYTECODE"]


@pytest.fixture(autouse=True)
def keep_root_logger() -> Iterator[None]:
    """Whatever a test does to the root logger (handlers, level) is undone after it."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for h in list(root.handlers):
        if h not in handlers:
            root.removeHandler(h)
    for h in handlers:
        if h not in root.handlers:
            root.addHandler(h)
    root.setLevel(level)


@pytest.fixture(params=["python", "compiled"])
def step_core(request: pytest.FixtureRequest) -> str:
    """Each step core in turn: "python" (motion/step_core.py) and "compiled" (motion/csrc,
    built by make venv; not built is a failure, not a skip)."""
    core = str(request.param)
    if core == "compiled":
        from motorctl.motion.compiled_core import unavailable

        why = unavailable()
        if why is not None:
            pytest.fail(why)
    return core


@pytest.fixture
def core_rig(step_core: str) -> Iterator[Callable[..., StepCoreRig]]:
    """``core_rig(**kw)``: a StepCoreRig (tests/support/rigs.py) on the step core of the
    test's parameter, closed after the test."""
    from tests.support.rigs import StepCoreRig

    rigs: list[StepCoreRig] = []

    def make(*args: Any, **kw: Any) -> StepCoreRig:
        rig = StepCoreRig(*args, core=step_core, **kw)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.close()


@pytest.fixture
def motorctld(tmp_path: Path) -> Iterator[StartDaemon]:
    """Start motorctld processes on PTYs (``DaemonProcess``; in the test's directory unless
    ``workdir`` is given): ``motorctld(config_text, **kw)``. Each is stopped at the end of
    the test (SIGTERM, or SIGKILL where started with ``kill_at_end=True``)."""
    from tests.support.daemon_proc import DaemonProcess

    started: list[tuple[DaemonProcess, bool]] = []

    def start(
        config_text: str | None = None,
        *,
        workdir: Path | None = None,
        kill_at_end: bool = False,
        **kw: Any,
    ) -> DaemonProcess:
        d = DaemonProcess(workdir or tmp_path, config_text, **kw)
        started.append((d, kill_at_end))
        return d.start()

    yield start
    for d, kill in reversed(started):
        if kill:
            d.kill()
        else:
            d.close()
