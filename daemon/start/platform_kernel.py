"""Where a PREEMPT_RT kernel comes from on this board and OS release: the platform check's
advice (daemon/start/platform_check.py) when the running kernel is not one, as
docs/raspberry-pi.md ("A real-time kernel") and docs/timing.md ("Checking a platform")
describe it.

Facts: the board's model (the device tree's, read by the platform check), the OS release
(``/etc/os-release``: ``ID``, ``VERSION_CODENAME``; :func:`read_os_release`, from a root
tests point at a fake tree), the running kernel's release (``uname -r``: Raspberry Pi OS's
kernels are ``...+rpt-rpi-v8`` and the like, Debian's ``...-arm64``) and the machine
(``uname -m``).

What this module knows, and no more (docs/raspberry-pi.md keeps the sources): Raspberry Pi
OS trixie's archive has ``linux-image-rpi-v8-rt``, the 64-bit PREEMPT_RT kernel
(``kernel8_rt.img``, chosen by ``kernel=kernel8_rt.img`` in /boot/firmware/config.txt),
and no RT flavour for the Pi 5's own 16K-page kernel (the v8 one runs a Pi 5 too); for
bookworm apt is asked; Debian's own kernels have an ``rt`` flavour per architecture.

Threads: the caller's; pure but for :func:`read_os_release`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: Raspberry Pi OS's PREEMPT_RT kernel package, its image and the config.txt line for it
RPI_RT_PACKAGE = "linux-image-rpi-v8-rt"
RPI_RT_IMAGE = "kernel8_rt.img"
RPI_CONFIG_LINE = f"kernel={RPI_RT_IMAGE}"
#: where docs/raspberry-pi.md says all of it
RPI_DOC = "docs/raspberry-pi.md, 'A real-time kernel'"
#: Debian's PREEMPT_RT kernel metapackage per machine (``uname -m``)
DEBIAN_RT = {"x86_64": "linux-image-rt-amd64", "aarch64": "linux-image-rt-arm64"}


@dataclass(frozen=True)
class OsRelease:
    """``/etc/os-release``'s ``ID`` and ``VERSION_CODENAME`` (empty when not said)."""

    id: str = ""
    codename: str = ""


def read_os_release(etc: Path = Path("/etc")) -> OsRelease | None:
    """The OS release under ``etc`` (its os-release, else /usr/lib's beside it); None when
    neither is readable."""
    for path in (etc / "os-release", etc.parent / "usr" / "lib" / "os-release"):
        try:
            text = path.read_text(errors="replace")
        except OSError:
            continue
        fields = {}
        for line in text.splitlines():
            key, sep, value = line.partition("=")
            if sep:
                fields[key.strip()] = value.strip().strip("\"'")
        return OsRelease(fields.get("ID", ""), fields.get("VERSION_CODENAME", ""))
    return None


def is_raspberry_pi(model: str | None) -> bool:
    """A Raspberry Pi board, by its device tree's model ("Raspberry Pi 4 Model B Rev 1.5",
    "Raspberry Pi Compute Module 4 ...", "Raspberry Pi 5 Model B ...")."""
    return bool(model) and str(model).startswith("Raspberry Pi")


def rt_kernel_advice(
    model: str | None, osr: OsRelease | None, kernel: str | None, machine: str
) -> str:
    """How to get a PREEMPT_RT kernel here, in one line of advice."""
    codename = osr.codename if osr else ""
    if is_raspberry_pi(model):
        return _raspberry_pi(str(model), osr, codename, kernel or "", machine)
    debian = DEBIAN_RT.get(machine)
    if osr is not None and osr.id == "debian" and debian:
        return f"install Debian's PREEMPT_RT kernel, 'apt install {debian}', and reboot into it"
    return (
        "boot a PREEMPT_RT kernel: your distribution's RT flavour, or a kernel 6.12 or "
        "later built with CONFIG_PREEMPT_RT"
    )


def _raspberry_pi(
    model: str, osr: OsRelease | None, codename: str, kernel: str, machine: str
) -> str:
    pi5 = any(name in model for name in ("Raspberry Pi 5", "Compute Module 5"))
    # the Pi 5's own kernel (kernel_2712.img, 16K pages) has no RT flavour: the v8 one runs it
    board = "; on a Pi 5 too: its own 16K-page kernel has no RT flavour" if pi5 else ""
    if machine != "aarch64":
        return (
            f"{model}: Raspberry Pi's PREEMPT_RT kernel ({RPI_RT_PACKAGE}) is 64-bit: install "
            f"the 64-bit Raspberry Pi OS, then follow {RPI_DOC}"
        )
    if kernel.endswith("-arm64") and "rpt" not in kernel:
        return f"{model}, Debian's own kernel: 'apt install {DEBIAN_RT['aarch64']}'"
    install = (
        f"'sudo apt install {RPI_RT_PACKAGE}', then '{RPI_CONFIG_LINE}' in "
        f"/boot/firmware/config.txt and reboot{board}"
    )
    if codename == "trixie":
        return f"{model}, Raspberry Pi OS trixie: {install}; {RPI_DOC}"
    if codename == "bookworm":
        return (
            f"{model}, Raspberry Pi OS bookworm: if 'apt-cache policy {RPI_RT_PACKAGE}' "
            f"shows a candidate, {install}; if not, move to trixie, whose archive has it, or "
            f"build the kernel; {RPI_DOC}"
        )
    name = codename or (osr.id if osr and osr.id else "unknown")
    return (
        f"{model}, OS release {name}: Raspberry Pi OS trixie packages a PREEMPT_RT kernel "
        f"({RPI_RT_PACKAGE}); on older releases build one; {RPI_DOC}"
    )
