"""hwtest/run (make test-hw) without a VM: where its cache goes, that it makes what it needs,
when it rebuilds, what it says when it cannot, and that a guest whose tests skip fails.

The real hwtest/run is copied into a throwaway repository whose hwtest/vm/build.sh and run.sh
are stand-ins: build.sh records the build and makes the folder (with the KERNEL record the
real one writes last: hwtest/vm/kernel_tuple.py's choice), run.sh records the boot and,
when asked, runs the guest's command on this machine in the real checkout, which has no
gpio-sim chip: exactly a guest whose gpio-sim failed to load. The real kernel_tuple.py reads
a recorded archive through stand-ins for apt-cache and apt-get (tests/support/apt_archive.py),
first on PATH; the tests move that archive on between runs.
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
from tests.support.apt_archive import TODAY, FakeArchive, fake_archive, replace_version, without

ROOT = REPO
#: the tests whose stand-in guest runs pytest (on the checkout, or on a guest's checkout
#: with the tier's plugins): several seconds each on 2 cores, so make test leaves them out
#: and make test-slow runs them (.ci/run does); the cache logic's tests stay in make test
GUEST_RUNS_PYTEST = pytest.mark.slow
TIMEOUT_S = 120.0
SYSTEM_PATH = "/usr/sbin:/usr/bin:/sbin:/bin"

FAKE_BUILD = """#!/bin/sh
echo "fake build into $1"
echo "build GSIM_APT_UPDATE=${GSIM_APT_UPDATE:-}" >> "$FAKE_LOG"
if [ -n "${FAKE_BUILD_FAIL:-}" ]; then echo "fake: the kernel download broke"; exit 1; fi
mkdir -p "$1" && touch "$1/initrd.img"
/usr/bin/python3 -I "$(dirname "$0")/kernel_tuple.py" > "$1/KERNEL"
"""
FAKE_RUN = """#!/bin/sh
spi=; [ "${GSIM_SPI:-0}" = 0 ] || spi=" spi=$GSIM_SPI"
echo "boot $GSIM_ROOT ${GSIM_BANKS:-}$spi" >> "$FAKE_LOG"
[ -n "${FAKE_GUEST:-}" ] || exit 0
cd "$FAKE_GUEST" && exec env -i PATH="$PATH" LANG=C.UTF-8 sh -c "$*"  # as bare as a guest's
"""


@dataclass
class Tier:
    repo: Path
    home: Path
    log: Path
    archive: FakeArchive

    def run(
        self,
        *args: str,
        env: dict[str, str | None] | None = None,
        as_nobody: bool = False,
        script: str = "hwtest/run",
    ) -> subprocess.CompletedProcess[str]:
        base = {
            "PATH": ":".join(
                (str(self.archive.bin), str(Path(sys.executable).parent), SYSTEM_PATH)
            ),
            "HOME": str(self.home),
            "FAKE_LOG": str(self.log),
            "LANG": "C.UTF-8",
        }
        for key, value in (env or {}).items():
            if value is None:
                base.pop(key, None)
            else:
                base[key] = value
        cmd = [str(self.repo / script), *args]
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
        for name in ("run", "digest.py", "vm/kernel_tuple.py"):
            shutil.copy(ROOT / "hwtest" / name, top / "repo" / "hwtest" / name)
        (vm / "build.sh").write_text(FAKE_BUILD)
        (vm / "run.sh").write_text(FAKE_RUN)
        for name in ("build.sh", "run.sh"):
            (vm / name).chmod(0o755)
        for name in ("init.sh", "spi-sim.c"):
            (vm / name).write_text(f"# {name}\n")
        home = top / "home"  # exists and is empty: no ~/.cache
        home.mkdir()
        yield Tier(top / "repo", home, top / "calls.log", fake_archive(top / "archive"))
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


TUPLE_TODAY = (
    "linux-image-6.1.0-56-amd64=6.1.192-2 linux-headers-6.1.0-56-amd64=6.1.192-2 "
    "linux-headers-6.1.0-56-common=6.1.192-2 linux-kbuild-6.1=6.1.192-3 "
    "linux-source-6.1=6.1.192-3"
)


def _cache(tier: Tier) -> Path:
    return tier.home / ".cache" / "motorctl-gpio-sim"


def test_the_tuple_and_whether_the_vm_was_built_now_are_said(tier: Tier) -> None:
    out = tier.run("v2")
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    lists = "updated now" if os.geteuid() == 0 else "as apt-get update last left them"
    assert lines[0] == f"hwtest: kernel tuple (apt lists {lists}): {TUPLE_TODAY}"
    assert lines[1].startswith(f"hwtest: building the VM into {_cache(tier)} (no VM there; ")
    assert lines[2].startswith("hwtest: VM built now, in ")
    assert lines[2].endswith(f" s, from: {TUPLE_TODAY}")
    assert (_cache(tier) / "KERNEL").read_text().split() == TUPLE_TODAY.split()
    out = tier.run("v2")
    assert out.stdout.splitlines()[1].startswith(
        f"hwtest: VM taken from the cache in {_cache(tier)} (built "
    )
    assert tier.builds() == 1


def test_a_vm_built_from_another_tuple_is_rebuilt_once(tier: Tier) -> None:
    """The archive moves on (a new revision of linux-kbuild-6.1 and linux-source-6.1): the VM
    cached with the old tuple is built again, once, saying from what."""
    assert tier.run("v2").returncode == 0
    moved = TODAY
    for name in ("linux-kbuild-6.1", "linux-source-6.1"):
        moved = replace_version(moved, name, "6.1.192-3", "6.1.192-4")
    tier.archive.record(moved)
    out = tier.run("v2")
    assert out.returncode == 0, out.stdout + out.stderr
    assert (
        "(built from another kernel tuple: linux-image-6.1.0-56-amd64=6.1.192-2 "
        "linux-headers-6.1.0-56-amd64=6.1.192-2 linux-headers-6.1.0-56-common=6.1.192-2 "
        "linux-kbuild-6.1=6.1.192-3 linux-source-6.1=6.1.192-3; log: "
    ) in out.stdout
    assert "linux-kbuild-6.1=6.1.192-4" in (_cache(tier) / "KERNEL").read_text()
    assert tier.builds() == 2
    assert "VM taken from the cache" in tier.run("v2").stdout
    assert tier.builds() == 2


def test_a_vm_without_its_kernel_record_is_rebuilt(tier: Tier) -> None:
    """build.sh removes KERNEL before it changes the VM and writes it last: a VM it did not
    finish (build.sh run by hand into the cache) is never taken as built."""
    assert tier.run("v2").returncode == 0
    (_cache(tier) / "KERNEL").unlink()
    out = tier.run("v2")
    assert "(built from another kernel tuple: none recorded; log: " in out.stdout
    assert tier.builds() == 2


def test_when_nothing_fits_the_run_fails_cache_or_not(tier: Tier) -> None:
    """An archive with no complete tuple: a fresh machine could not build the VM, so a
    machine with a cached one does not pass either."""
    assert tier.run("v2").returncode == 0
    tier.archive.record(
        without(without(TODAY, "linux-source-6.1", "6.1.192"), "linux-kbuild-6.1", "6.1.176")
    )
    out = tier.run("v2")
    assert out.returncode == 1
    first, second = out.stderr.splitlines()
    assert first.startswith("kernel_tuple: no complete kernel tuple: linux-image-6.1.0-56-amd64 ")
    assert second.startswith("hwtest: no VM can be built from the archive as it is now")
    assert tier.builds() == 1 and tier.log.read_text().count("boot") == 1  # the first run's


def test_the_lists_are_updated_first_as_root(tier: Tier) -> None:
    if os.geteuid() != 0:
        pytest.skip("apt-get update is run as root only")
    assert tier.run("vm").returncode == 0
    assert tier.archive.calls() == ["apt-get update -qq -o DPkg::Lock::Timeout=600"]
    # build.sh uses the lists the choice saw: it does not update them again
    assert "build GSIM_APT_UPDATE=0" in tier.log.read_text()
    out = tier.run("vm", env={"GSIM_APT_UPDATE": "0"})
    assert "(apt lists as apt-get update last left them)" in out.stdout
    assert len(tier.archive.calls()) == 1
    (tier.archive.folder / "update-fails").touch()
    out = tier.run("v2")
    assert out.returncode == 1
    assert "E: Failed to fetch" in out.stderr
    assert "GSIM_APT_UPDATE=0 takes the lists as they are" in out.stderr
    assert "boot" not in tier.log.read_text()


def test_vm_builds_or_takes_the_vm_and_boots_nothing(tier: Tier) -> None:
    out = tier.run("vm")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "hwtest: VM built now" in out.stdout
    out = tier.run("vm")
    assert out.returncode == 0 and "hwtest: VM taken from the cache" in out.stdout
    assert tier.builds() == 1 and "boot" not in tier.log.read_text()


FAKE_MAKE = """#!/bin/sh
echo "make $*" >> "$FAKE_LOG"
"""


def test_ci_says_before_its_parts_which_kernel_and_whether_the_vm_was_built_now(
    tier: Tier,
) -> None:
    """.ci/run (its parts stood in for by a make that records): `hwtest/run vm` before the
    parts, the tuple and built-now or cached in its output and in its summary; with
    CI_VM_CACHE, a VM built from another tuple than the archive's is built again."""
    if os.geteuid() != 0:
        pytest.skip(".ci/run builds the VM only as root")
    (tier.repo / ".ci").mkdir()
    shutil.copy(ROOT / ".ci" / "run", tier.repo / ".ci" / "run")
    make = tier.archive.bin / "make"
    make.write_text(FAKE_MAKE)
    make.chmod(0o755)
    cache = tier.home.parent / "ci-vm"

    def ci(tuple_line: str = TUPLE_TODAY) -> list[str]:
        """What `hwtest/run vm` said after the tuple, before the parts."""
        out = tier.run(script=".ci/run", env={"CI_VM_CACHE": str(cache), "CI_SERIAL": "1"})
        assert out.returncode == 0, out.stdout + out.stderr
        lines = out.stdout.splitlines()
        assert lines[0] == "== .ci/run: hwtest/run vm", lines
        assert lines[1] == f"hwtest: kernel tuple (apt lists updated now): {tuple_line}"
        parts = lines.index("== .ci/run: make test")
        # the tests make test leaves out and the conformance suite on dSPIN chips right after
        # make test, each alone too
        after = lines[parts + 1 :]
        assert after[0].startswith("== .ci/run: make test: passed in "), lines
        assert after[1] == "== .ci/run: make test-slow", lines
        assert after[2].startswith("== .ci/run: make test-slow: passed in "), lines
        assert after[3] == "== .ci/run: make test-dspin", lines
        vm_part = "== .ci/run: hwtest/run vm: passed in "
        assert lines[parts - 1].startswith(vm_part), lines
        said = lines[2 : parts - 1]
        # the summary: each part's result and, after the VM's, the tuple and its last line
        summary = lines[max(i for i, line in enumerate(lines) if line.startswith(vm_part)) :]
        assert summary[1:3] == [f"== .ci/run: {lines[1]}", f"== .ci/run: {said[-1]}"], summary
        assert summary[-1].startswith("== .ci/run: all parts in "), summary
        return said

    first = ci()
    assert first[0].startswith(f"hwtest: building the VM into {cache} (no VM there; ")
    assert first[1].startswith("hwtest: VM built now, in ") and len(first) == 2
    cached = ci()
    assert len(cached) == 1
    assert cached[0].startswith(f"hwtest: VM taken from the cache in {cache} (built ")
    moved = replace_version(TODAY, "linux-source-6.1", "6.1.192-3", "6.1.192-4")
    tier.archive.record(moved)
    again = ci(TUPLE_TODAY.replace("source-6.1=6.1.192-3", "source-6.1=6.1.192-4"))
    assert again[0].startswith(
        f"hwtest: building the VM into {cache} (built from another kernel tuple: "
        f"{TUPLE_TODAY}; log: "
    )
    assert again[1].startswith("hwtest: VM built now, in ")
    assert tier.builds() == 2
    out = tier.run("vm", env={"MOTORCTL_GSIM_CACHE": str(cache)})
    assert "hwtest: VM taken from the cache" in out.stdout


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


@GUEST_RUNS_PYTEST
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
    root; pypi: PyPI's gpiod in the venv on the host's root. v2 and v1 with the SPI bus a
    program answers (the dSPIN chain, hwtest/test_dspin_daemon.py), pypi without."""
    for which, root, spi in (
        ("v2", "trixie", " spi=user"),
        ("v1", "rootfs", " spi=user"),
        ("pypi", "host", ""),
    ):
        out = tier.run(which)
        assert out.returncode == 0, out.stdout + out.stderr
        assert tier.log.read_text().splitlines()[-1] == f"boot {root} 32 16{spi}"
        assert f"GSIM_ROOT={root})" in out.stdout


@GUEST_RUNS_PYTEST
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


@GUEST_RUNS_PYTEST
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


@GUEST_RUNS_PYTEST
def test_a_bad_deadline_is_named(tier: Tier) -> None:
    guest = _guest_with_the_plugins(tier)
    out = tier.run("pypi", env={"FAKE_GUEST": str(guest), "HWTEST_DEADLINE_S": "soon"})
    assert out.returncode != 0
    assert "HWTEST_DEADLINE_S='soon': not a number of seconds" in out.stdout + out.stderr


@GUEST_RUNS_PYTEST
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
