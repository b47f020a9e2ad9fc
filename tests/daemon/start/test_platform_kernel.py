"""Where a PREEMPT_RT kernel comes from (daemon/start/platform_kernel.py): the OS release read
from a fake /etc, the advice for a Raspberry Pi by its OS release, its word size and its
kernel, for Debian elsewhere, and docs/raspberry-pi.md saying the same."""

from __future__ import annotations

from pathlib import Path

import pytest

from motorctl.daemon.start.platform_kernel import (
    RPI_CONFIG_LINE,
    RPI_RT_PACKAGE,
    OsRelease,
    is_raspberry_pi,
    read_os_release,
    rt_kernel_advice,
)
from tests.support import REPO

PI4 = "Raspberry Pi 4 Model B Rev 1.5"
TRIXIE = OsRelease("debian", "trixie")
BOOKWORM = OsRelease("debian", "bookworm")


def test_the_os_release_is_read_from_etc_else_usr_lib(tmp_path: Path) -> None:
    etc = tmp_path / "etc"
    etc.mkdir()
    assert read_os_release(etc) is None
    lib = tmp_path / "usr" / "lib"
    lib.mkdir(parents=True)
    (lib / "os-release").write_text('ID=raspbian\nVERSION_CODENAME="bookworm"\n')
    assert read_os_release(etc) == OsRelease("raspbian", "bookworm")
    (etc / "os-release").write_text("PRETTY_NAME='Debian GNU/Linux 13 (trixie)'\nID=debian\n")
    assert read_os_release(etc) == OsRelease("debian", "")


def test_a_raspberry_pi_is_known_by_its_model() -> None:
    assert is_raspberry_pi(PI4) and is_raspberry_pi("Raspberry Pi Compute Module 4 Rev 1.0")
    assert not is_raspberry_pi(None) and not is_raspberry_pi("Pine64 RockPro64 v2.1")


def test_raspberry_pi_os_trixie_installs_the_packaged_rt_kernel() -> None:
    tip = rt_kernel_advice(PI4, TRIXIE, "6.12.47+rpt-rpi-v8", "aarch64")
    assert tip == (
        f"{PI4}, Raspberry Pi OS trixie: 'sudo apt install {RPI_RT_PACKAGE}', then "
        f"'{RPI_CONFIG_LINE}' in /boot/firmware/config.txt and reboot; docs/raspberry-pi.md, "
        "'A real-time kernel'"
    )
    pi5 = rt_kernel_advice(
        "Raspberry Pi 5 Model B Rev 1.0", TRIXIE, "6.12.47+rpt-rpi-2712", "aarch64"
    )
    assert f"'{RPI_CONFIG_LINE}' in /boot/firmware/config.txt and reboot; on a Pi 5 too: " in pi5


def test_bookworm_asks_apt_first_and_names_the_ways_without_it() -> None:
    tip = rt_kernel_advice(PI4, BOOKWORM, "6.12.25+rpt-rpi-v8", "aarch64")
    assert f"Raspberry Pi OS bookworm: if 'apt-cache policy {RPI_RT_PACKAGE}' shows" in tip
    assert "if not, move to trixie, whose archive has it, or build the kernel" in tip


@pytest.mark.parametrize(
    ("model", "osr", "kernel", "machine", "says"),
    [
        (PI4, TRIXIE, "6.12.47+rpt-rpi-v7l", "armv7l", "is 64-bit: install the 64-bit"),
        (PI4, BOOKWORM, "6.1.0-18-arm64", "aarch64", "Debian's own kernel: 'apt install "),
        (PI4, OsRelease("debian", "bullseye"), "6.1.21-v8+", "aarch64", "OS release bullseye"),
        (PI4, None, "6.6.31+rpt-rpi-v8", "aarch64", "OS release unknown"),
        (None, BOOKWORM, "6.1.0-18-amd64", "x86_64", "'apt install linux-image-rt-amd64'"),
        (None, OsRelease("fedora", "40"), "6.8.5", "x86_64", "your distribution's RT flavour"),
    ],
)
def test_every_other_case_gets_its_own_way(
    model: str | None, osr: OsRelease | None, kernel: str, machine: str, says: str
) -> None:
    assert says in rt_kernel_advice(model, osr, kernel, machine)


def test_docs_raspberry_pi_says_what_the_advice_says() -> None:
    """The platform check points at docs/raspberry-pi.md's section; that section names the
    same package, image line, apt question and the Pi 5's case."""
    text = (REPO / "docs" / "raspberry-pi.md").read_text()
    section = text.split("### A real-time kernel", 1)[1].split("\n## ", 1)[0]
    for words in (
        f"sudo apt install {RPI_RT_PACKAGE}",
        RPI_CONFIG_LINE,
        f"apt-cache policy {RPI_RT_PACKAGE}",
        "trixie",
        "bookworm",
        "Pi 5",
        "uname -v",
        "/sys/kernel/realtime",
    ):
        assert words in section, words
