"""The systemd units: hardening score, `systemd-analyze verify`, and real-time priority without
capabilities (LimitRTPRIO/LimitMEMLOCK only) measured on this kernel.

Four units, all installed verbatim by the package (debian/rules): motorctld.service (one
daemon) and the template motorctld@.service (one daemon per instance name, each with its own
config, serving place and state directory), the template the single unit line for line but
for the lines that name those; motorctl-metrics.timer and the service it starts (the metrics
for node_exporter; installed disabled). `make test-deb` checks both again as installed on a
fresh Debian 12 root, and runs two instances of the template under a booted systemd.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO

ROOT = REPO
UNIT = ROOT / "systemd" / "motorctld.service"
TEMPLATE = ROOT / "systemd" / "motorctld@.service"
METRICS = ROOT / "systemd" / "motorctl-metrics.service"
TIMER = ROOT / "systemd" / "motorctl-metrics.timer"
MAX_EXPOSURE = 2.0
#: each service with the name it is checked under (a template as one of its instances)
UNITS = [
    pytest.param(UNIT, "motorctld.service", id="single"),
    pytest.param(TEMPLATE, "motorctld@left.service", id="template"),
    pytest.param(METRICS, "motorctl-metrics.service", id="metrics"),
]

analyze = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(analyze is None, reason="systemd-analyze is not installed")


def exposure(unit: Path, root: Path | None = None, name: str | None = None) -> float:
    """The overall exposure of ``unit`` (a file), or of unit ``name`` found under ``root``."""
    assert analyze is not None
    cmd = [analyze, "security", "--offline=true", "--no-pager"]
    if root is not None:
        cmd.append(f"--root={root}")
    out = subprocess.run([*cmd, name or str(unit)], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", out.stdout + out.stderr)
    assert m, out.stdout + out.stderr
    return float(m.group(1))


def installed_root(tmp_path: Path, unit: Path) -> Path:
    """A root laid out as the package installs it (the unit and /usr/bin/motorctld)."""
    units = tmp_path / "lib" / "systemd" / "system"
    shutil.copytree("/lib/systemd/system", units, symlinks=True)  # the targets it needs
    shutil.copy(unit, units / unit.name)
    (tmp_path / "usr" / "bin").mkdir(parents=True)
    daemon = tmp_path / "usr" / "bin" / "motorctld"
    daemon.write_text(f"#!{sys.executable}\nfrom motorctl.daemon.start.main import main\nmain()\n")
    daemon.chmod(0o755)
    (tmp_path / "bin").mkdir()
    shutil.copy(os.path.realpath("/bin/sh"), tmp_path / "bin" / "sh")  # the metrics' ExecStart
    return tmp_path


@needs_analyze
@pytest.mark.parametrize(("unit", "name"), UNITS)
def test_security_exposure_at_most_2(unit: Path, name: str, tmp_path: Path) -> None:
    assert exposure(unit, installed_root(tmp_path, unit), name) <= MAX_EXPOSURE


@needs_analyze
def test_the_template_is_exposed_no_more_than_the_single_unit(tmp_path: Path) -> None:
    single = exposure(UNIT, installed_root(tmp_path / "a", UNIT), "motorctld.service")
    template = exposure(TEMPLATE, installed_root(tmp_path / "b", TEMPLATE), "motorctld@b.service")
    assert template <= single


@needs_analyze
@pytest.mark.parametrize(
    ("unit", "name"), [*UNITS, pytest.param(TIMER, "motorctl-metrics.timer", id="timer")]
)
def test_verify_clean(unit: Path, name: str, tmp_path: Path) -> None:
    """verify, without its look for the man: pages of Documentation= (it asks this machine's
    man, which has not the package's pages: tests/packaging/test_deb_docs.py and make test-deb
    open every Documentation= target)."""
    root = installed_root(tmp_path, unit)
    if unit == TIMER:  # a timer without its service is refused
        shutil.copy(METRICS, root / "lib" / "systemd" / "system" / METRICS.name)
    assert analyze is not None
    out = subprocess.run(
        [analyze, "verify", "--man=no", f"--root={root}", f"lib/systemd/system/{name}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0 and not out.stderr.strip(), out.stderr


@pytest.mark.parametrize(("unit", "suffix"), [(UNIT, ""), (TEMPLATE, "-%i")])
def test_unit_needs_no_group_that_debian_lacks(unit: Path, suffix: str) -> None:
    text = unit.read_text()
    assert "SupplementaryGroups" not in text  # groups come from sysusers.d membership
    assert "User=motorctl" in text and "/opt/" not in text
    for line in (
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
        "PrivateNetwork=yes",
        "RestrictAddressFamilies=AF_UNIX",
        "DevicePolicy=closed",
        "CapabilityBoundingSet=",
        f"RuntimeDirectory=motorctl{suffix}",
        f"StateDirectory=motorctl{suffix}",
        "Type=notify",
    ):
        assert line in text.splitlines(), line


def settings(unit: Path) -> list[str]:
    return [line for line in unit.read_text().splitlines() if line and not line.startswith("#")]


#: the only settings in which an instance differs from the single daemon: its name, its
#: config, where it serves, its state and runtime directories
INSTANCE_LINES = {
    "Description=motorctl: motor-controller protocol daemon, instance %i",
    "ExecStartPre=/usr/bin/motorctld --check-config /etc/motorctl/%i.toml",
    'Environment="MOTORCTLD_SERVE=--pty /run/motorctl-%i/motorctl.pty"',
    "EnvironmentFile=-/etc/default/motorctld-%i",
    "ExecStart=/usr/bin/motorctld --config /etc/motorctl/%i.toml --state-dir /run/motorctl-%i"
    " $MOTORCTLD_SERVE",
    "RuntimeDirectory=motorctl-%i",
    "StateDirectory=motorctl-%i",
}


def test_the_template_is_the_single_unit_but_for_the_instance_lines() -> None:
    """systemd has no include: the template repeats the single unit's hardening, and this
    keeps the two in step (a setting added to one and not the other fails here)."""
    single, template = settings(UNIT), settings(TEMPLATE)
    differing = [line for line in template if line not in single]
    assert set(differing) == INSTANCE_LINES, differing
    assert len(template) == len(single)
    same = [line for line in template if line not in INSTANCE_LINES]
    assert same == [line for line in single if line in same], "same settings, same order"
    assert "%i" not in "".join(single) and "%I" not in TEMPLATE.read_text()


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
    cmd = [
        "prlimit",
        f"--rtprio={rtprio}",
        f"--memlock={memlock}",
        "setpriv",
        "--reuid=65534",
        "--regid=65534",
        "--clear-groups",
        "--inh-caps=-all",
        "--bounding-set=-all",
        sys.executable,
        "-c",
        RT_PROBE,
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd="/")
    return out.returncode, out.stdout.strip() + out.stderr.strip()


needs_root = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None,
    reason="needs root and setpriv to become an unprivileged user",
)


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


def test_the_metrics_command_docs_service_md_shows_is_the_units() -> None:
    """docs/service.md, "Metrics", quotes the command of motorctl-metrics.service: the same
    words as the unit's ExecStart runs (its sh -c script)."""
    unit = METRICS.read_text().replace("\\\n", " ")
    exec_start = re.search(r"^ExecStart=/bin/sh -c '(.*)'$", unit, re.M)
    assert exec_start, "ExecStart=/bin/sh -c '...'"
    page = (ROOT / "docs" / "service.md").read_text()
    quoted = re.search(r"a oneshot that runs\n\n```sh\n(.*?)```", page, re.S)
    assert quoted, "docs/service.md quotes no metrics command"
    assert quoted.group(1).replace("\\\n", " ").split() == exec_start.group(1).split()
