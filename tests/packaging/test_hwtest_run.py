"""hwtest/run (make test-hw) without a VM: where its cache goes, that it makes what it needs,
when it rebuilds, what it says when it cannot, and that a guest whose tests skip fails.

The real hwtest/run is copied into a throwaway repository whose hwtest/vm/build.sh and run.sh
are stand-ins: build.sh records the build and makes the folder, run.sh records the boot and,
when asked, runs the guest's command on this machine in the real checkout, which has no
gpio-sim chip: exactly a guest whose gpio-sim failed to load.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hwtest.no_skips import PREFIX
from tests.support import REPO

ROOT = REPO
TIMEOUT_S = 120.0

FAKE_BUILD = """#!/bin/sh
echo "fake build into $1"
echo build >> "$FAKE_LOG"
if [ -n "${FAKE_BUILD_FAIL:-}" ]; then echo "fake: the kernel download broke"; exit 1; fi
mkdir -p "$1" && touch "$1/initrd.img"
"""
FAKE_RUN = """#!/bin/sh
echo "boot $GSIM_ROOT ${GSIM_BANKS:-}" >> "$FAKE_LOG"
[ -n "${FAKE_GUEST:-}" ] || exit 0
cd "$FAKE_GUEST" && exec env -i PATH="$PATH" LANG=C.UTF-8 sh -c "$*"  # as bare as a guest's
"""


@dataclass
class Tier:
    repo: Path
    home: Path
    log: Path

    def run(
        self, *args: str, env: dict[str, str | None] | None = None, as_nobody: bool = False
    ) -> subprocess.CompletedProcess[str]:
        base = {
            "PATH": f"{Path(sys.executable).parent}:/usr/sbin:/usr/bin:/sbin:/bin",
            "HOME": str(self.home),
            "FAKE_LOG": str(self.log),
            "LANG": "C.UTF-8",
        }
        for key, value in (env or {}).items():
            if value is None:
                base.pop(key, None)
            else:
                base[key] = value
        cmd = [str(self.repo / "hwtest" / "run"), *args]
        if as_nobody:
            cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *cmd]
        return subprocess.run(
            cmd, env=base, capture_output=True, text=True, timeout=TIMEOUT_S, cwd="/"
        )

    def builds(self) -> int:
        return self.log.read_text().split().count("build") if self.log.exists() else 0


@pytest.fixture
def tier() -> Iterator[Tier]:
    # world-readable, so that the same tree serves a run as an unprivileged user
    top = Path(tempfile.mkdtemp(prefix="hwtest-run-"))
    top.chmod(0o755)
    try:
        vm = top / "repo" / "hwtest" / "vm"
        vm.mkdir(parents=True)
        for name in ("run", "digest.py"):
            shutil.copy(ROOT / "hwtest" / name, top / "repo" / "hwtest" / name)
        (vm / "build.sh").write_text(FAKE_BUILD)
        (vm / "run.sh").write_text(FAKE_RUN)
        for name in ("build.sh", "run.sh"):
            (vm / name).chmod(0o755)
        for name in ("init.sh", "spi-sim.c"):
            (vm / name).write_text(f"# {name}\n")
        home = top / "home"  # exists and is empty: no ~/.cache
        home.mkdir()
        yield Tier(top / "repo", home, top / "calls.log")
    finally:
        shutil.rmtree(top)


def test_first_run_with_an_empty_home_makes_the_cache_folder(tier: Tier) -> None:
    out = tier.run("v2", env={"XDG_CACHE_HOME": None})
    assert out.returncode == 0, out.stdout + out.stderr
    cache = tier.home / ".cache" / "motorctl-gpio-sim"
    assert (cache / "STAMP").is_file() and (cache / "initrd.img").is_file()
    build_log = tier.home / ".cache" / "motorctl-gpio-sim.build.log"
    assert f"fake build into {cache}" in build_log.read_text()
    assert f"log: {build_log}" in out.stdout
    assert tier.builds() == 1 and "boot trixie 32 16" in tier.log.read_text()


def test_the_cache_is_built_once_and_again_when_the_recipe_changes(tier: Tier) -> None:
    for _ in range(2):
        assert tier.run("v2").returncode == 0
    assert tier.builds() == 1
    with (tier.repo / "hwtest" / "vm" / "init.sh").open("a") as f:
        f.write("# changed\n")
    out = tier.run("v2")
    assert out.returncode == 0 and "recipe changed" in out.stdout
    assert tier.builds() == 2


def test_xdg_cache_home_is_honoured_and_created(tier: Tier) -> None:
    xdg = tier.home.parent / "xdg" / "nested"
    assert tier.run("v2", env={"XDG_CACHE_HOME": str(xdg)}).returncode == 0
    assert (xdg / "motorctl-gpio-sim" / "STAMP").is_file()
    assert (xdg / "motorctl-gpio-sim.build.log").is_file()
    assert not (tier.home / ".cache").exists()


def test_a_relative_xdg_cache_home_is_ignored(tier: Tier) -> None:
    """The XDG spec: a relative path is invalid and is ignored."""
    assert tier.run("v2", env={"XDG_CACHE_HOME": "relative/cache"}).returncode == 0
    assert (tier.home / ".cache" / "motorctl-gpio-sim" / "STAMP").is_file()


def test_motorctl_gsim_cache_wins(tier: Tier) -> None:
    mine = tier.home.parent / "mine" / "vm"
    out = tier.run(
        "v2",
        env={
            "MOTORCTL_GSIM_CACHE": str(mine) + "/",
            "XDG_CACHE_HOME": str(tier.home.parent / "xdg"),
        },
    )
    assert out.returncode == 0, out.stderr
    assert (mine / "STAMP").is_file() and (mine.parent / "vm.build.log").is_file()
    assert not (tier.home.parent / "xdg").exists()


def test_a_failed_build_says_so_and_is_tried_again(tier: Tier) -> None:
    out = tier.run("v2", env={"FAKE_BUILD_FAIL": "1"})
    assert out.returncode == 1
    assert "fake: the kernel download broke" in out.stdout
    assert "VM build failed (log: " in out.stderr
    assert not (tier.home / ".cache" / "motorctl-gpio-sim" / "STAMP").exists()
    assert "boot" not in tier.log.read_text()
    assert tier.run("v2").returncode == 0 and tier.builds() == 2


def test_a_cache_folder_it_cannot_make_is_named_with_the_fix(tier: Tier) -> None:
    blocker = tier.home.parent / "a-file"
    blocker.write_text("")
    out = tier.run("v2", env={"XDG_CACHE_HOME": str(blocker / "cache")})
    assert out.returncode == 2
    assert f"cannot write {blocker}/cache/motorctl-gpio-sim.build.log" in out.stderr
    assert "MOTORCTL_GSIM_CACHE" in out.stderr
    assert tier.builds() == 0


def test_no_home_and_no_xdg_is_named(tier: Tier) -> None:
    out = tier.run("v2", env={"HOME": None, "XDG_CACHE_HOME": None})
    assert out.returncode == 2
    assert "neither HOME nor XDG_CACHE_HOME is set" in out.stderr


def test_building_needs_root_and_says_how(tier: Tier) -> None:
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("needs setpriv to become an unprivileged user")
        out = tier.run(
            "v2", as_nobody=True, env={"HOME": None, "MOTORCTL_GSIM_CACHE": str(tier.home / "c")}
        )
    else:
        out = tier.run("v2", env={"MOTORCTL_GSIM_CACHE": str(tier.home / "c")})
    assert out.returncode == 2
    assert "building it needs root once" in out.stderr
    assert f"sudo MOTORCTL_GSIM_CACHE={tier.home / 'c'} hwtest/run v2" in out.stderr
    assert tier.builds() == 0


def test_a_guest_whose_tests_all_skip_fails(tier: Tier) -> None:
    """The guest's command, run here where there is no gpio-sim chip: every hardware test
    skips itself, and the tier must fail rather than report '0 passed, N skipped'."""
    out = tier.run(
        "v2", "--ignore=tests/contract", "-k", "test_backend", env={"FAKE_GUEST": str(ROOT)}
    )
    assert out.returncode == 1, out.stdout[-3000:] + out.stderr[-3000:]
    assert f"{PREFIX}: needs gpio-sim (make test-hw)" in out.stdout
    assert " 0 passed" not in out.stdout and " passed" not in out.stdout.splitlines()[-2]
    assert "== hwtest: v2 API: FAILED (1)" in out.stdout


def test_each_binding_boots_its_own_root(tier: Tier) -> None:
    """v2: Debian 13's python3-libgpiod in the trixie root; v1: Debian 12's in the bookworm
    root; pypi: PyPI's gpiod in the venv on the host's root."""
    for which, root in (("v2", "trixie"), ("v1", "rootfs"), ("pypi", "host")):
        out = tier.run(which)
        assert out.returncode == 0, out.stdout + out.stderr
        assert tier.log.read_text().splitlines()[-1] == f"boot {root} 32 16"
        assert f"GSIM_ROOT={root})" in out.stdout


def test_layouts_boot_without_chips_and_run_only_the_layout_tests(tier: Tier) -> None:
    """`hwtest/run layouts`: a guest per binding with no gpio-sim chip of its own (the tests
    make each board's), running hwtest/test_layouts.py alone; here, where there is no
    gpio-sim, its tests skip, which the tier reports as failures."""
    out = tier.run("layouts", env={"FAKE_GUEST": str(ROOT)})
    assert tier.log.read_text().splitlines()[-2:] == ["boot trixie none", "boot rootfs none"]
    assert out.returncode == 2, out.stdout[-3000:] + out.stderr[-3000:]
    assert f"{PREFIX}: needs gpio-sim without chips of its own (hwtest/run layouts)" in out.stdout
    assert "hwtest/test_layouts.py::test_the_example_runs_unchanged[pi5-2026]" in out.stdout
    assert "test_backend" not in out.stdout and "test_contract" not in out.stdout
    assert "== hwtest: board layouts, v1 API: FAILED (1)" in out.stdout


HANGS = """
import threading
import time


def helper() -> None:
    time.sleep(60)


def test_hangs() -> None:
    threading.Thread(target=helper, name="helper", daemon=True).start()
    time.sleep(60)
"""


def _guest_with_the_plugins(tier: Tier) -> Path:
    """A guest's checkout (FAKE_GUEST) holding the tier's pytest plugins and no tests."""
    guest = tier.repo.parent / "guest"
    (guest / "hwtest").mkdir(parents=True)
    for name in ("__init__.py", "no_skips.py", "deadline.py"):
        shutil.copy(ROOT / "hwtest" / name, guest / "hwtest" / name)
    return guest


def test_a_test_that_hangs_ends_its_guest_and_is_named_at_the_end(tier: Tier) -> None:
    """A guest whose test never returns: hwtest/deadline.py ends its pytest after
    HWTEST_DEADLINE_S with each thread's stack, instead of the whole GSIM_TIMEOUT going by;
    the run's last lines name the stuck test and where its threads were."""
    guest = _guest_with_the_plugins(tier)
    (guest / "tests" / "contract").mkdir(parents=True)
    (guest / "tests" / "contract" / "test_fine.py").write_text(
        "def test_fine() -> None:\n    pass\n"
    )
    (guest / "hwtest" / "test_stuck.py").write_text(HANGS)
    out = tier.run("pypi", env={"FAKE_GUEST": str(guest), "HWTEST_DEADLINE_S": "2"})
    assert out.returncode == 1, out.stdout[-3000:] + out.stderr[-3000:]
    tail = out.stdout[
        out.stdout.index("== hwtest: what failed in v2 API, PyPI gpiod:") :
    ].splitlines()
    assert tail[1] == (
        "  hwtest/test_stuck.py::test_hangs ran past its HWTEST_DEADLINE_S "
        "(hwtest/deadline.py); its threads:"
    ), tail
    frames = [line for line in tail if line.startswith("    File ")]
    assert any('test_stuck.py", line 12 in test_hangs' in line for line in frames), tail
    assert any('test_stuck.py", line 7 in helper' in line for line in frames), tail
    assert "tests/contract/test_fine.py::test_fine PASSED" in out.stdout


def test_a_bad_deadline_is_named(tier: Tier) -> None:
    guest = _guest_with_the_plugins(tier)
    out = tier.run("pypi", env={"FAKE_GUEST": str(guest), "HWTEST_DEADLINE_S": "soon"})
    assert out.returncode != 0
    assert "HWTEST_DEADLINE_S='soon': not a number of seconds" in out.stdout + out.stderr


def test_the_core_for_the_trixie_root_is_built_once_and_by_the_guest_when_not_here(
    tier: Tier,
) -> None:
    """The compiled core for the trixie root's Python 3.13: as root, hwtest/run builds it in
    that root on this machine (chroot); where that fails (here: a root with no shell), it
    says so and the guest builds it, once per run (the layouts' v2 guest does not)."""
    cache = tier.home / ".cache" / "motorctl-gpio-sim"
    out = tier.run("v2")  # builds the (fake) VM
    assert out.returncode == 0, out.stdout + out.stderr
    (cache / "trixie" / "usr" / "bin").mkdir(parents=True)
    (cache / "trixie" / "mnt").mkdir()
    python = cache / "trixie" / "usr" / "bin" / "python3"
    python.write_text("#!/bin/sh\nexit 0\n")
    python.chmod(0o755)
    guest = tier.repo.parent / "guest"
    guest.mkdir()
    (guest / "setup.py").write_text("import sys\nprint('the guest builds', sys.argv[1:])\n")
    out = tier.run("all", env={"FAKE_GUEST": str(guest)})
    tried = "== hwtest: building the compiled core in"
    if os.geteuid() == 0:
        assert out.stdout.count(f"{tried} {cache}/trixie failed here (above)") == 1, out.stdout
    else:
        assert tried not in out.stdout, out.stdout
    assert out.stdout.count("the guest builds ['-q', 'build_ext', '--inplace'") == 1, out.stdout
