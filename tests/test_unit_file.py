"""The systemd unit: hardening score, `systemd-analyze verify`, and real-time priority without
capabilities (LimitRTPRIO/LimitMEMLOCK only) measured on this kernel.

The unit checked here is the file the package installs verbatim (debian/rules); `make
test-deb` checks it again as installed on a fresh Debian 12 root.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "systemd" / "motorctld.service"
MAX_EXPOSURE = 2.0

analyze = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(analyze is None, reason="systemd-analyze is not installed")


def exposure(unit: Path, root: Path | None = None) -> float:
    assert analyze is not None
    cmd = [analyze, "security", "--offline=true", "--no-pager"]
    if root is not None:
        cmd.append(f"--root={root}")
    out = subprocess.run([*cmd, str(unit)], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", out.stdout + out.stderr)
    assert m, out.stdout + out.stderr
    return float(m.group(1))


@needs_analyze
def test_security_exposure_at_most_2() -> None:
    assert exposure(UNIT) <= MAX_EXPOSURE


@needs_analyze
def test_verify_clean(tmp_path: Path) -> None:
    """Against a root laid out as the package installs it (the unit and /usr/bin/motorctld)."""
    units = tmp_path / "lib" / "systemd" / "system"
    shutil.copytree("/lib/systemd/system", units, symlinks=True)  # the targets it needs
    shutil.copy(UNIT, units / UNIT.name)
    (tmp_path / "usr" / "bin").mkdir(parents=True)
    daemon = tmp_path / "usr" / "bin" / "motorctld"
    daemon.write_text(f"#!{sys.executable}\nfrom motorctl.daemon.main import main\nmain()\n")
    daemon.chmod(0o755)
    assert analyze is not None
    out = subprocess.run([analyze, "verify", f"--root={tmp_path}",
                          f"lib/systemd/system/{UNIT.name}"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and not out.stderr.strip(), out.stderr


def test_unit_needs_no_group_that_debian_lacks() -> None:
    text = UNIT.read_text()
    assert "SupplementaryGroups" not in text  # groups come from sysusers.d membership
    assert "User=motorctl" in text and "/opt/" not in text
    for line in ("NoNewPrivileges=yes", "ProtectSystem=strict", "PrivateNetwork=yes",
                 "RestrictAddressFamilies=AF_UNIX", "DevicePolicy=closed", "CapabilityBoundingSet=",
                 "RuntimeDirectory=motorctl", "StateDirectory=motorctl", "Type=notify"):
        assert line in text.splitlines(), line


RT_PROBE = """
import ctypes, os, sys
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    fifo = "ok"
except OSError as exc:
    fifo = exc.strerror
libc = ctypes.CDLL(None, use_errno=True)
lock = "ok" if libc.mlockall(3) == 0 else os.strerror(ctypes.get_errno())
print(fifo, "|", lock)
"""


def probe_as_nobody(rtprio: str, memlock: str) -> tuple[int, str]:
    """Run the probe as an unprivileged user with no capabilities and these limits."""
    cmd = ["prlimit", f"--rtprio={rtprio}", f"--memlock={memlock}", "setpriv",
           "--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all",
           "--bounding-set=-all", sys.executable, "-c", RT_PROBE]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd="/")
    return out.returncode, out.stdout.strip() + out.stderr.strip()


needs_root = pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None,
                                reason="needs root and setpriv to become an unprivileged user")


@needs_root
def test_without_limits_an_unprivileged_daemon_gets_no_realtime() -> None:
    code, out = probe_as_nobody("0", "65536")
    assert code == 0, out
    fifo, lock = (s.strip() for s in out.split("|"))
    assert fifo == "Operation not permitted"
    assert lock != "ok"


@needs_root
def test_limits_alone_give_realtime_without_capabilities() -> None:
    """What the unit relies on: LimitRTPRIO=99 and LimitMEMLOCK=infinity, no capability."""
    code, out = probe_as_nobody("99", "unlimited")
    if code != 0 and "failed to set the" in out:
        pytest.skip(f"this machine cannot raise the limits (no CAP_SYS_RESOURCE): {out}")
    assert code == 0, out
    assert out.replace(" ", "") == "ok|ok"
