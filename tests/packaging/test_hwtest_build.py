"""hwtest/vm/build.sh, the real script, where it must stop: never a half-built VM that
hwtest/run takes as built. Run against a recorded archive through stand-ins for apt-cache and
apt-get (tests/support/apt_archive.py; the stand-in apt-get installs and fetches nothing), so
it stops at the latest where it would download the kernel packages.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.support import REPO
from tests.support.apt_archive import TODAY, FakeArchive, fake_archive, without

BUILD = REPO / "hwtest" / "vm" / "build.sh"
NOTHING_FITS = without(without(TODAY, "linux-source-6.1", "6.1.192"), "linux-kbuild-6.1", "6.1.176")


def build(archive: FakeArchive, cache: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BUILD), str(cache)],
        env={
            "PATH": f"{archive.bin}:/usr/sbin:/usr/bin:/sbin:/bin",
            "LANG": "C.UTF-8",
            "HOME": str(cache.parent),
            "GSIM_APT_UPDATE": "0",
        },
        capture_output=True,
        text=True,
        timeout=120,
    )


def a_whole_vm(cache: Path) -> dict[str, str]:
    """A cache folder as a finished build leaves it (the files that matter here)."""
    cache.mkdir()
    files = {"KERNEL": "linux-image-6.1.0-55-amd64=6.1.192-1\n", "initrd.img": "old"}
    for name, text in files.items():
        (cache / name).write_text(text)
    return files


def test_nothing_fits_stops_before_anything_is_installed_or_changed(tmp_path: Path) -> None:
    archive = fake_archive(tmp_path / "archive", NOTHING_FITS)
    cache = tmp_path / "vm"
    files = a_whole_vm(cache)
    out = build(archive, cache)
    assert out.returncode == 1, out.stdout + out.stderr
    assert out.stderr.splitlines() == [
        out.stderr.splitlines()[0],
        "build.sh: no VM built: no complete kernel tuple in the archive (the line above names "
        "what is missing)",
    ]
    assert out.stderr.startswith(
        "kernel_tuple: no complete kernel tuple: linux-image-6.1.0-56-amd64 6.1.192-2 lacks "
        "linux-source-6.1 6.1.192-*"
    )
    assert archive.calls() == []  # nothing installed, nothing downloaded
    assert {p.name: p.read_text() for p in cache.iterdir()} == files  # the old VM as it was


def test_a_build_that_does_not_finish_leaves_no_kernel_record(tmp_path: Path) -> None:
    """Past the choice (printed, every package), the VM is being changed: its KERNEL record
    goes first, so hwtest/run never takes what is left for a VM."""
    archive = fake_archive(tmp_path / "archive")
    cache = tmp_path / "vm"
    a_whole_vm(cache)
    out = build(archive, cache)
    assert out.returncode != 0
    for line in (
        "linux-image-6.1.0-56-amd64=6.1.192-2",
        "linux-headers-6.1.0-56-amd64=6.1.192-2",
        "linux-headers-6.1.0-56-common=6.1.192-2",
        "linux-kbuild-6.1=6.1.192-3",
        "linux-source-6.1=6.1.192-3",
    ):
        assert f"  {line}\n" in out.stdout
    assert any(
        call.endswith(
            " download linux-image-6.1.0-56-amd64=6.1.192-2 "
            "linux-headers-6.1.0-56-amd64=6.1.192-2 "
            "linux-headers-6.1.0-56-common=6.1.192-2 linux-kbuild-6.1=6.1.192-3 "
            "linux-source-6.1=6.1.192-3 busybox-static"
        )
        for call in archive.calls()
    ), archive.calls()
    assert "build.sh: no download of linux-image-6.1.0-56-amd64=6.1.192-2" in out.stderr
    assert not (cache / "KERNEL").exists()
