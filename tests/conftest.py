"""What every test shares.

The tests mirror the package, one folder a room and a sub-folder a wing (daemon/link/,
state/, status/; motion/executors/ and its process/; hal/backends/gpiod/, hal/layers/tmc/;
protocol/capture/), each test file named after the module it tests, at the same place:
test_<module>.py, or test_<module>_<part>.py for one part of a module's tests (``_e2e``:
against motorctld as a process on a real PTY); tests/hal/backends/gpiod/test_config.py tests
hal/backends/gpiod/config.py. At the top, the package's own rules: test_layout.py (the
tests' mirror, modules' and functions' sizes) and test_imports.py (the import graph):

    protocol/   client/   daemon/   motion/   hal/    the rooms' tests
    contract/   the backend contract (the mock here; gpiod on gpio-sim in hwtest/run)
    docs/       the README's walkthrough run as written; every path the pages name exists
    packaging/  debian/, the wheel, the systemd units, --version, hwtest/run and its VM's
                build (madison/: the Debian archive's kernel packages as recorded)
    support/    the shared rigs, one module each: wait (``until``, the deadline wait),
                frames, rigs (the engine or the step core on a virtual clock), executors (a
                stand-in executor that records, the ramp executor over TMC5160 models, the
                process executor, the rings' slots written by hand), inprocess
                (``LiveDaemon``: an in-process daemon serving a real PTY), daemon_proc
                (``DaemonProcess``), sessions (``SessionRig``: the link's session and
                silence watch in front of a daemon on a virtual clock), stalls (a step
                executor whose stop confirmations stall), spi_bench and tmc_model (TMC
                chips on a fake SPI bus), mock_factory (the mock backend as gpiozero's mock
                factory), line_requests (a recording GPIO request, a PWM sysfs tree),
                stand_ins (the environment for tests/fakegpiod/ and tests/fakespi/), fsutil,
                tamper (a forwarder that changes one answer: the replay's tests), traces
                (made-up trace files: the trace format's, its readers' and the recorder's
                tests), socat (socat's PTY pair: a serial device that goes away and
                comes back), apt_archive (apt-cache and apt-get answering from recorded
                `apt-cache madison` output: the hardware tier's kernel choice)
    deb/        make test-deb's install check; fakegpiod/, fakespi/: stand-in modules

This file is also loaded for tests/contract in the hardware tier's guests: it imports
nothing beyond pytest at module level. Here: the ``motorctld`` fixture (daemons as
processes, stopped after their test), ``step_core`` and ``core_rig`` (a test run on each
step core, Python and compiled), ``mock_factory`` (simulated machines through the registry,
closed after the test, as gpiozero hands its mock factory to every test) and ``spi_bench``
(TMC chip models on a fake SPI bus), and for every test:

- The root logger is put back after each test. A test that runs motorctld's ``main()`` in
  this process (``--print-default-config``, ``--check-config``) installs the daemon's stderr
  handler; left in place, it printed the INFO lines of later tests' link threads (which may
  log after their test ended) between pytest's dots.
- Hypothesis's examples have no deadline (its default: 200 ms each): a timed test in
  disguise, which fails on a loaded machine or under emulation (the arm64 lane runs
  tests/protocol under qemu) for nothing the test is about; timing belongs in bench/.
- The processes the tests start (daemons, their step executors, the CLIs) keep their
  compiled bytecode in ``build/pycache`` when the environment says not to write any beside
  the sources (``PYTHONDONTWRITEBYTECODE``): otherwise each daemon start compiled the whole
  package twice (the daemon and its executor process), a tenth of a second of CPU at every
  one of the suite's hundred-odd starts. The bytecode is the same either way.

``MOTORCTL_WORLD=dspin`` (``make test-dspin``: the modules marked ``conformance``) runs
the conformance suite's daemons on docs/examples/dspin.toml's dSPIN chips instead of the
embedded default's STEP/DIR motors (tests/support/daemon_proc.py: ``world``,
``for_world``); the tests about the step executor itself (marked ``stepdir``) are
deselected there.

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
    from tests.support.mock_factory import MockFactory
    from tests.support.rigs import StepCoreRig
    from tests.support.spi_bench import SpiBench


def pytest_configure(config: pytest.Config) -> None:
    no_deadline()
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        cache = config.rootpath / "build" / "pycache"
        cache.mkdir(parents=True, exist_ok=True)
        os.environ["PYTHONPYCACHEPREFIX"] = str(cache)
        del os.environ["PYTHONDONTWRITEBYTECODE"]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In the dSPIN world (``MOTORCTL_WORLD=dspin``, ``make test-dspin``) the tests about
    the STEP/DIR step executor (marked ``stepdir``) are deselected: its motors have none."""
    if os.environ.get("MOTORCTL_WORLD") != "dspin":
        return
    kept = [i for i in items if i.get_closest_marker("stepdir") is None]
    if len(kept) < len(items):
        config.hook.pytest_deselected(items=[i for i in items if i not in kept])
        items[:] = kept


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
    """Each step core in turn: "python" (motion/executors/step_core.py) and "compiled"
    (motion/executors/csrc/, built by make venv; not built is a failure, not a skip)."""
    core = str(request.param)
    if core == "compiled":
        from motorctl.motion.executors.compiled_core import unavailable

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


@pytest.fixture
def mock_factory() -> Iterator[MockFactory]:
    """The mock backend as gpiozero's mock factory (tests/support/mock_factory.py): simulated
    machines built through the registry, all closed after the test."""
    from tests.support.mock_factory import MockFactory

    factory = MockFactory()
    yield factory
    factory.close()


@pytest.fixture
def spi_bench() -> SpiBench:
    """TMC chip models on a fake SPI bus and a virtual clock (tests/support/spi_bench.py)."""
    from tests.support.spi_bench import SpiBench

    return SpiBench()


def no_deadline() -> None:
    """Every test's Hypothesis examples without a deadline (the module's docstring says
    why). The hardware tier's guests run tests/contract without Hypothesis: nothing to set
    there."""
    try:
        from hypothesis import settings
    except ModuleNotFoundError:
        return
    settings.register_profile("motorctl", deadline=None)
    settings.load_profile("motorctl")
