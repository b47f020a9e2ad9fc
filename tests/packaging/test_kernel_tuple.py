"""hwtest/vm/kernel_tuple.py: the kernel packages the hardware tier's VM is built from, chosen
from what Debian's archive holds now, fed recorded `apt-cache madison` output (today's,
tests/packaging/madison/, and variants of it: consistent, the source missing, nothing that
fits). The command runs as build.sh and hwtest/run run it: the host's /usr/bin/python3 -I
(no venv), reading the archive through apt-cache (a stand-in answering from the recording:
tests/support/apt_archive.py)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from hwtest.vm import kernel_tuple as kt
from tests.support import REPO
from tests.support.apt_archive import TODAY, fake_archive, replace_version, without

HOST_PYTHON = "/usr/bin/python3"
SCRIPT = REPO / "hwtest" / "vm" / "kernel_tuple.py"
ABI = "6.1.0-56"


def chosen(madison: str, abi: str = ABI, fallback: bool = True) -> kt.Choice:
    return kt.choose(kt.parse_madison(madison), abi, fallback)


def lines(choice: kt.Choice) -> list[str]:
    return choice.chosen.lines()


def madison(name: str, version: str, where: str = "bookworm-security/main amd64 Packages") -> str:
    """One line as apt-cache madison prints it."""
    return f"{name} | {version} | http://deb.debian.org/debian-security {where}\n"


# --- Debian's version order -----------------------------------------------------------

ORDERED = [  # each pair a < b
    ("6.1.192-2", "6.1.192-3"),
    ("6.1.192-9", "6.1.192-10"),
    ("6.1.176-1", "6.1.192-1"),
    ("6.1.99-1", "6.1.100-1"),
    ("6.12.117-1~deb12u1", "6.12.117-1"),
    ("1.0~rc1-1", "1.0-1"),
    ("1.0", "1.0-1"),
    ("9.9-9", "1:0.1-1"),
    ("1.0a-1", "1.0+b1-1"),
    ("1.0-1", "1.0-1+b1"),
    ("2:1.0-1", "10:0.1-1"),
]


@pytest.mark.parametrize(("a", "b"), ORDERED)
def test_versions_are_ordered_as_debian_orders_them(a: str, b: str) -> None:
    assert kt.compare_versions(a, b) == -1
    assert kt.compare_versions(b, a) == 1
    assert kt.compare_versions(a, a) == 0


@pytest.mark.skipif(shutil.which("dpkg") is None, reason="needs dpkg (Debian) to compare with")
def test_the_order_is_dpkgs() -> None:
    for a, b in ORDERED:
        assert subprocess.run(["dpkg", "--compare-versions", a, "lt", b]).returncode == 0
    assert kt.compare_versions("1.0-01", "1.0-1") == 0
    assert subprocess.run(["dpkg", "--compare-versions", "1.0-01", "eq", "1.0-1"]).returncode == 0


def test_the_upstream_version_is_the_version_without_the_debian_revision() -> None:
    assert kt.upstream_of("6.1.192-2") == "6.1.192"
    assert kt.upstream_of("6.12.117-1~deb12u1") == "6.12.117"
    assert kt.upstream_of("1:2.0-3-4") == "1:2.0-3"
    assert kt.upstream_of("2.0") == "2.0"


def test_madison_lines_are_read_once_each_newest_first_binary_only() -> None:
    archive = kt.parse_madison(
        TODAY + madison("linux-source-6.1", "6.1.199-1", "bookworm/main Sources")
    )
    assert archive["linux-image-6.1.0-50-amd64"] == ["6.1.176-1"]  # in main and security
    assert archive["linux-source-6.1"][:3] == ["6.1.192-3", "6.1.192-2", "6.1.192-1"]
    assert "6.1.199-1" not in archive["linux-source-6.1"]


# --- the choice -----------------------------------------------------------------------


def test_today_image_and_headers_at_one_version_kbuild_and_source_at_their_newest_revision() -> (
    None
):
    """The archive as it is today: linux-kbuild-6.1 6.1.192-2 does not exist (the old
    recipe's `E: Version '6.1.192-2' for 'linux-kbuild-6.1' was not found`)."""
    choice = chosen(TODAY)
    assert lines(choice) == [
        "linux-image-6.1.0-56-amd64=6.1.192-2",
        "linux-headers-6.1.0-56-amd64=6.1.192-2",
        "linux-headers-6.1.0-56-common=6.1.192-2",
        "linux-kbuild-6.1=6.1.192-3",
        "linux-source-6.1=6.1.192-3",
    ]
    assert choice.note == "" and choice.chosen.kver == "6.1.0-56-amd64"


def test_a_consistent_archive_gives_one_version() -> None:
    kbuild = replace_version(TODAY, "linux-kbuild-6.1", "6.1.192-3", "6.1.192-2")
    consistent = without(kbuild, "linux-source-6.1") + madison("linux-source-6.1", "6.1.192-2")
    choice = chosen(consistent)
    assert {line.split("=")[1] for line in lines(choice)} == {"6.1.192-2"}
    assert choice.note == ""


def test_kbuild_or_source_of_another_upstream_version_is_never_taken() -> None:
    """A newer linux-kbuild-6.1 of a newer kernel (6.1.193) is not the image's kernel."""
    newer = replace_version(TODAY, "linux-kbuild-6.1", "6.1.192-3", "6.1.193-1")
    choice = chosen(newer)
    assert "linux-kbuild-6.1 6.1.192-* (the archive has 6.1.193-1, 6.1.176-1)" in choice.note
    assert choice.chosen.abi == "6.1.0-50"


def test_the_source_missing_takes_the_newest_complete_older_tuple() -> None:
    """No linux-source-6.1 of 6.1.192: 6.1.0-56 and -55 lack it, -54 and -53 lack kbuild of
    their versions, -52 and -51 have no headers in the archive: the point release's -50."""
    choice = chosen(without(TODAY, "linux-source-6.1", "6.1.192"))
    assert lines(choice) == [
        "linux-image-6.1.0-50-amd64=6.1.176-1",
        "linux-headers-6.1.0-50-amd64=6.1.176-1",
        "linux-headers-6.1.0-50-common=6.1.176-1",
        "linux-kbuild-6.1=6.1.176-1",
        "linux-source-6.1=6.1.176-1",
    ]
    assert choice.chosen.kver == "6.1.0-50-amd64"  # the image the modules are built against
    assert choice.note == (
        "linux-image-6.1.0-56-amd64 6.1.192-2 lacks linux-source-6.1 6.1.192-* (the archive "
        "has 6.1.190-1, 6.1.187-1, 6.1.176-1, 6.1.170-3): taking the newest complete tuple of "
        "an older version"
    )


def test_an_older_abi_of_a_newer_version_is_not_taken() -> None:
    """Older means older: an ABI whose image is newer than the current one's is left."""
    newer = without(TODAY, "linux-source-6.1", "6.1.192") + "".join(
        madison(name, "6.1.195-1")
        for name in (
            "linux-image-6.1.0-57-amd64",
            "linux-headers-6.1.0-57-amd64",
            "linux-headers-6.1.0-57-common",
            "linux-kbuild-6.1",
            "linux-source-6.1",
        )
    )
    assert chosen(newer).chosen.abi == "6.1.0-50"
    assert chosen(newer, abi="6.1.0-57").chosen.abi == "6.1.0-57"


NOTHING_FITS = without(without(TODAY, "linux-source-6.1", "6.1.192"), "linux-kbuild-6.1", "6.1.176")


def test_nothing_fits_names_what_is_missing() -> None:
    with pytest.raises(kt.NoTuple) as e:
        chosen(NOTHING_FITS)
    assert str(e.value) == (
        "no complete kernel tuple: linux-image-6.1.0-56-amd64 6.1.192-2 lacks linux-source-6.1 "
        "6.1.192-* (the archive has 6.1.190-1, 6.1.187-1, 6.1.176-1, 6.1.170-3); nor is any "
        "older one: the newest, linux-image-6.1.0-55-amd64 6.1.192-1, lacks linux-source-6.1 "
        "6.1.192-* (the archive has 6.1.190-1, 6.1.187-1, 6.1.176-1, 6.1.170-3)"
    )


def test_an_abi_asked_for_is_taken_or_refused_never_replaced() -> None:
    assert chosen(TODAY, abi="6.1.0-55", fallback=False).chosen.lines()[0] == (
        "linux-image-6.1.0-55-amd64=6.1.192-1"
    )
    with pytest.raises(kt.NoTuple, match=r"lacks linux-kbuild-6.1 6.1.190-\* .*GSIM_KVER"):
        chosen(TODAY, abi="6.1.0-54", fallback=False)
    with pytest.raises(kt.NoTuple, match=r"linux-image-6\.1\.0-99-amd64: not in the archive"):
        chosen(TODAY, abi="6.1.0-99", fallback=False)


def test_an_abi_of_another_naming_is_refused_by_name() -> None:
    with pytest.raises(kt.NoTuple, match=r"'6.12.117\+deb12' is not of the form X.Y.Z-N"):
        chosen(TODAY, abi="6.12.117+deb12")


# --- the command, as build.sh and hwtest/run run it ------------------------------------


def run(tmp_path: Path, madison: str, *args: str) -> subprocess.CompletedProcess[str]:
    archive = fake_archive(tmp_path / "archive", madison)
    return subprocess.run(
        [HOST_PYTHON, "-I", str(SCRIPT), *args],
        env={"PATH": f"{archive.bin}:/usr/bin:/bin", "LANG": "C.UTF-8"},
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )


def test_the_command_prints_the_five_packages_with_the_hosts_python(tmp_path: Path) -> None:
    out = run(tmp_path, TODAY)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == lines(chosen(TODAY))
    assert out.stderr == ""


def test_the_command_says_why_when_it_takes_an_older_abi(tmp_path: Path) -> None:
    out = run(tmp_path, without(TODAY, "linux-source-6.1", "6.1.192"))
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0] == "linux-image-6.1.0-50-amd64=6.1.176-1"
    assert out.stderr.startswith("kernel_tuple: linux-image-6.1.0-56-amd64 6.1.192-2 lacks ")


def test_the_command_fails_in_one_line_when_nothing_fits(tmp_path: Path) -> None:
    out = run(tmp_path, NOTHING_FITS)
    assert out.returncode == 1
    assert out.stdout == ""
    assert out.stderr.count("\n") == 1
    assert out.stderr.startswith("kernel_tuple: no complete kernel tuple: ")


def test_the_command_with_kver(tmp_path: Path) -> None:
    out = run(tmp_path, TODAY, "--kver", "6.1.0-54-amd64")
    assert out.returncode == 1 and out.stdout == ""
    assert "GSIM_KVER=6.1.0-54-amd64" in out.stderr
    out = run(tmp_path / "2", TODAY, "--kver", "6.1.0-50")
    assert out.returncode == 1 and "not an amd64 kernel" in out.stderr


def test_without_apt_cache_the_command_says_so(tmp_path: Path) -> None:
    out = subprocess.run(
        [HOST_PYTHON, "-I", str(SCRIPT)],
        env={"PATH": str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1
    assert out.stderr == (
        "kernel_tuple: apt-cache not found: the VM is built from Debian's packages\n"
    )
