"""debian/ in step with the tree: version, metadata for old and new setuptools, users, udev, unit.

The package itself is built and installed on a fresh Debian 12 root by `make test-deb`
(tests/deb/check-install.sh); these checks are quick and catch drift in every `make test`.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from motorctl import __version__
from tests.support import REPO

ROOT = REPO
DEBIAN = ROOT / "debian"


def test_changelog_version_is_the_package_version() -> None:
    first = (DEBIAN / "changelog").read_text().splitlines()[0]
    m = re.match(r"motorctl \(([^)-]+)-\d+\) ", first)
    assert m, first
    assert m.group(1) == __version__, (
        f"debian/changelog says {m.group(1)}, motorctl/__init__.py {__version__}: "
        "add a changelog entry (dch -v VERSION-1)"
    )


#: prints the metadata setup.py and pyproject.toml give under the running setuptools
METADATA = """
import json, warnings
import setuptools
from distutils.core import run_setup
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    m = run_setup("setup.py", stop_after="config").metadata
print(json.dumps({"setuptools": setuptools.__version__, "name": m.get_name(),
    "version": m.get_version(), "license": m.license,
    "license_expression": getattr(m, "license_expression", None),
    "warnings": [f"{w.category.__name__}: {w.message}" for w in caught
        # setuptools' own: 78 (Debian 13) loads every command to check [tool.distutils],
        # and its develop command imports pkg_resources, which warns that it is deprecated
        if not str(w.message).startswith("pkg_resources is deprecated as an API")]}))
"""


def interpreters() -> list[str]:
    """This interpreter, and Debian's python3 when it is another with its own setuptools (on
    Debian 12, setuptools 66: what make deb and make test-root SUITE=bookworm build with)."""
    found = [sys.executable]
    debian = Path("/usr/bin/python3")
    if debian.exists() and debian.resolve() != Path(sys.executable).resolve():
        has = subprocess.run([debian, "-c", "import setuptools"], capture_output=True, timeout=60)
        if has.returncode == 0:
            found.append(str(debian))
    return found


@pytest.mark.parametrize("python", interpreters())
def test_the_metadata_builds_with_old_and_new_setuptools(python: str) -> None:
    """pyproject.toml and setup.py read by Debian 12's setuptools 66 (no PEP 639 there) and by
    the newest (which deprecates the table form of the licence): the name, the version and
    the licence, in the form that setuptools writes, without a deprecation warning."""
    run = subprocess.run(
        [python, "-c", METADATA], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stdout + run.stderr
    meta = json.loads(run.stdout)
    assert (meta["name"], meta["version"]) == ("motorctl", __version__), meta
    if int(meta["setuptools"].split(".")[0]) >= 77:
        assert (meta["license_expression"], meta["license"]) == ("MIT", None), meta
    else:
        assert meta["license"] == "MIT", meta
    assert not [w for w in meta["warnings"] if "Deprecat" in w.split(":")[0]], meta


def test_the_package_build_patches_nothing() -> None:
    """debian/ builds the tree as it is: a patch that rewrote pyproject.toml for Debian 12
    (the licence's form) is what the metadata test above made unneeded."""
    assert not (DEBIAN / "patches").exists()


def test_sysusers_and_udev() -> None:
    users = (DEBIAN / "motorctl.sysusers").read_text()
    assert re.search(r"^u motorctl - .* /usr/sbin/nologin$", users, re.M)
    for group in ("dialout", "gpio", "spi"):
        assert re.search(rf"^m motorctl {group}$", users, re.M), group
    rules = (DEBIAN / "motorctl.udev").read_text()
    assert 'KERNEL=="gpiochip*", GROUP="motorctl", MODE="0660"' in rules
    assert 'KERNEL=="spidev*", GROUP="motorctl", MODE="0660"' in rules


def test_unit_serves_what_the_default_file_says() -> None:
    unit = (ROOT / "systemd" / "motorctld.service").read_text()
    default = (ROOT / "systemd" / "motorctld.default").read_text()
    assert "EnvironmentFile=-/etc/default/motorctld" in unit
    assert "$MOTORCTLD_SERVE" in unit
    assert re.search(r'^MOTORCTLD_SERVE="--pty /run/motorctl/motorctl.pty"$', default, re.M)
    assert 'Environment="MOTORCTLD_SERVE=--pty /run/motorctl/motorctl.pty"' in unit
    assert "--config /etc/motorctl/motorctl.toml" in unit


# What the package build runs of the tree itself (debian/rules: the example config and
# help2man's --help/--version of both programs), and the Debian package of every module from
# outside the standard library that it may import.
BUILD_RUNS = (
    ("motorctl.daemon.start.main", "--print-default-config"),
    ("motorctl.daemon.start.main", "--help"),
    ("motorctl.daemon.start.main", "--version"),
    ("motorctl.client.cli", "--help"),
    ("motorctl.client.cli", "--version"),
)
DEBIAN_PACKAGE_OF = {
    "serial": "python3-serial",
    "gpiod": "python3-libgpiod",
    "spidev": "python3-spidev",
    "systemd": "python3-systemd",
}
IMPORTED = r"""
import runpy, sys
module, arg = sys.argv[1:]
sys.argv = [module, arg]
try:
    runpy.run_module(module, run_name="__main__")
except SystemExit:
    pass
tops = {name.split(".")[0] for name in list(sys.modules)}
# site's own hooks: Debian's python3 has a sitecustomize (libpython3.X-minimal) that site imports
hooks = {"sitecustomize", "usercustomize"}
print(" ".join(sorted(t for t in tops if t != "motorctl" and not t.startswith("_")
                      and t not in sys.stdlib_module_names and t not in hooks)), file=sys.stderr)
"""


def build_depends() -> set[str]:
    control = (DEBIAN / "control").read_text()
    m = re.search(r"^Build-Depends:(.*?)^\S", control, re.M | re.S)
    assert m, control
    return {dep.split()[0] for dep in m.group(1).replace("\n", " ").split(",") if dep.strip()}


def test_build_depends_has_what_the_build_imports() -> None:
    """The package build runs the tree under Debian's python3 in a root holding only the
    Build-Depends (make deb): every module those runs import must come from one of them."""
    rules = (DEBIAN / "rules").read_text()
    deps = build_depends()
    for module, arg in BUILD_RUNS:
        assert module in rules, f"debian/rules no longer runs {module}: update BUILD_RUNS"
        out = subprocess.run(
            [sys.executable, "-c", IMPORTED, module, arg],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=ROOT,
        )
        imported = out.stderr.strip().splitlines()[-1].split() if out.stderr.strip() else []
        for top in imported:
            assert top in DEBIAN_PACKAGE_OF, (
                f"{module} {arg} imports {top!r}: add its Debian package to DEBIAN_PACKAGE_OF "
                "and to Build-Depends"
            )
            assert DEBIAN_PACKAGE_OF[top] in deps, (
                f"{module} {arg} imports {top!r} at build time (debian/rules runs it): "
                f"add {DEBIAN_PACKAGE_OF[top]} to Build-Depends in debian/control"
            )


def test_build_depends_parsed() -> None:
    deps = build_depends()
    assert {"debhelper-compat", "dh-python", "help2man", "pybuild-plugin-pyproject"} <= deps


def test_the_template_is_installed_and_its_instances_are_restarted_and_stopped() -> None:
    rules = (DEBIAN / "rules").read_text()
    assert (
        "install -D -m 0644 systemd/motorctld@.service "
        "debian/motorctl/lib/systemd/system/motorctld@.service"
    ) in rules
    # dh_installsystemd --name=motorctld handles the single unit only: a template has no
    # instance to enable, so the maintainer scripts look after the ones the admin made
    assert "dh_installsystemd --name=motorctld" in rules
    # ... and then move to /usr/lib (one package for Debian 12 and 13: debian/rules says why)
    assert "mv debian/motorctl/lib/systemd/system debian/motorctl/usr/lib/systemd/system" in rules
    postinst = (DEBIAN / "motorctl.postinst").read_text()
    assert "systemctl --no-block try-restart 'motorctld@*.service'" in postinst
    prerm = (DEBIAN / "motorctl.prerm").read_text()
    assert "#DEBHELPER#" in prerm and '"$1" = "remove"' in prerm
    assert "systemctl stop 'motorctld@*.service'" in prerm


def test_an_instance_has_its_own_config_serving_place_and_state() -> None:
    unit = (ROOT / "systemd" / "motorctld@.service").read_text()
    lines = unit.splitlines()
    assert "EnvironmentFile=-/etc/default/motorctld-%i" in lines
    assert 'Environment="MOTORCTLD_SERVE=--pty /run/motorctl-%i/motorctl.pty"' in lines
    assert "ExecStartPre=/usr/bin/motorctld --check-config /etc/motorctl/%i.toml" in lines
    (start,) = [ln for ln in lines if ln.startswith("ExecStart=")]
    assert "--config /etc/motorctl/%i.toml" in start and "$MOTORCTLD_SERVE" in start
    # the state directory the daemon is given is the runtime directory systemd makes for it
    assert "--state-dir /run/motorctl-%i " in start and "RuntimeDirectory=motorctl-%i" in lines
    assert "StateDirectory=motorctl-%i" in lines


def test_the_package_is_built_per_architecture_with_the_compiled_step_core() -> None:
    """The compiled step core makes the package Architecture: any, built against the headers
    of every supported Python 3 (python3-all-dev, dh-python), linked to libc only."""
    control = (DEBIAN / "control").read_text()
    assert re.search(r"^Architecture: any$", control, re.M)
    assert "python3-all-dev" in build_depends()
    depends = re.search(r"^Depends:(.*?)^\S", control, re.M | re.S)
    assert depends and "${shlibs:Depends}" in depends.group(1)
