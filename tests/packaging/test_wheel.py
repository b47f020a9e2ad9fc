"""The wheel installs one top-level package, `motorctl` (with its compiled step core), and
lives beside python-daemon.

Marked `packaging`: builds the wheel with `pip wheel` (setuptools from PyPI, in pip's build
isolation) and installs it with python-daemon (whose import name is `daemon`) from PyPI in a
throwaway virtual environment, in both orders, uninstalling either and checking the other
still imports and works; mypy --strict type-checks code against the installed wheel. Needs
PyPI (or the configured index); pip's downloads are cached in the test's temporary directory.
Deselect with `-m "not packaging"` when offline. Marked `slow` too: `make test-slow` runs it
(a part of .ci/run of its own), not `make test`.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import motorctl
from tests.support import REPO

ROOT = REPO
STEP_TIMEOUT_S = 300.0

# slow too: make test leaves it out (about 30 s on 2 cores), make test-slow runs it (.ci/run)
pytestmark = [pytest.mark.packaging, pytest.mark.slow]

DAEMON_WORKS = (
    "import daemon, daemon.pidfile, os; "
    "assert os.sep + 'site-packages' + os.sep + 'daemon' in daemon.__file__, daemon.__file__; "
    "ctx = daemon.DaemonContext(working_directory='/'); "
    "assert ctx.working_directory == '/'; print('python-daemon ok')"
)
MOTORCTL_WORKS = (
    "import motorctl, motorctl.daemon.start.main, motorctl.hal.backends.mock.world\n"
    "import motorctl.client.cli\n"
    "from motorctl.daemon.config import load_config\n"
    "assert len(load_config(None).motors) == 3\n"
    "from motorctl.motion.executors import compiled_core\n"
    "assert compiled_core.unavailable() is None, compiled_core.unavailable()\n"
    "print('motorctl ok', motorctl.__version__)"
)


class Env:
    """A throwaway virtual environment driven by this interpreter's pip (`pip --python`)."""

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp / "venv"
        self.cache = tmp / "pip-cache"
        self.env = {
            **os.environ,
            "PIP_CACHE_DIR": str(self.cache),
            "PIP_DISABLE_PIP_VERSION_CHECK": "1",
        }
        self.env.pop("PYTHONPATH", None)
        run([sys.executable, "-m", "venv", "--without-pip", str(self.dir)], self.env, tmp)
        self.python = self.dir / "bin" / "python"

    def pip(self, *args: str) -> str:
        return run(
            [sys.executable, "-m", "pip", "--python", str(self.python), *args], self.env, self.dir
        )

    def python_c(self, code: str) -> str:
        # Run from an empty directory so nothing of the checkout is importable by accident.
        return run([str(self.python), "-c", code], self.env, self.dir)

    def works(self, motorctl_installed: bool, daemon_installed: bool) -> None:
        if daemon_installed:
            assert "python-daemon ok" in self.python_c(DAEMON_WORKS)
        else:
            assert "No module named 'daemon'" in self.fails("import daemon")
        if motorctl_installed:
            assert f"motorctl ok {motorctl.__version__}" in self.python_c(MOTORCTL_WORKS)
            version = run([str(self.dir / "bin" / "motorctld"), "--version"], self.env, self.dir)
            assert version.strip() == f"motorctld {motorctl.__version__}"
        else:
            assert "No module named 'motorctl'" in self.fails("import motorctl")

    def mypy_sees_the_wheel(self, tmp: Path) -> None:
        """mypy --strict, pointed at the venv, type-checks code using the installed wheel."""
        user = tmp / "user"
        user.mkdir()
        (user / "use.py").write_text(
            "from motorctl.daemon.config import load_config\n"
            "from motorctl.protocol.codec import wrap24\n"
            "position: int = wrap24(1 << 23)\n"
            "reveal_type(load_config(None).motors[0].homing.source)\n",
            encoding="utf-8",
        )
        out = run(
            [
                sys.executable,
                "-m",
                "mypy",
                "--strict",
                "--python-executable",
                str(self.python),
                "--cache-dir",
                str(tmp / "mypy-cache"),
                "use.py",
            ],
            self.env,
            user,
        )
        assert 'Revealed type is "motorctl.motion.types.HomingSource"' in out, out

    def fails(self, code: str) -> str:
        proc = subprocess.run(
            [str(self.python), "-c", code],
            env=self.env,
            cwd=self.dir,
            capture_output=True,
            text=True,
            timeout=STEP_TIMEOUT_S,
        )
        assert proc.returncode != 0, f"{code!r} should fail: {proc.stdout}"
        return proc.stderr


def run(cmd: list[str], env: dict[str, str], cwd: Path) -> str:
    proc = subprocess.run(
        cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=STEP_TIMEOUT_S
    )
    assert proc.returncode == 0, f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}"
    return proc.stdout


def build_wheel(tmp: Path, env: dict[str, str]) -> Path:
    """`pip wheel` of a clean copy of the checkout (an in-tree build would reuse build/)."""
    src = tmp / "src"
    junk = shutil.ignore_patterns(
        ".venv",
        ".git",
        "build",
        "*.egg-info",
        "__pycache__",
        ".*_cache",
        ".hypothesis",
        ".run",
        "*.pty",
        "*.so",
    )
    shutil.copytree(ROOT, src, symlinks=True, ignore=junk)
    out = tmp / "wheels"
    run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(src)],
        env,
        tmp,
    )
    (wheel,) = out.glob("motorctl-*.whl")
    return wheel


def test_wheel_has_one_top_level_package_and_coexists_with_python_daemon(tmp_path: Path) -> None:
    env = Env(tmp_path)
    wheel = build_wheel(tmp_path, env.env)

    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
        top = {name.split("/")[0] for name in names}
        dist_info = f"motorctl-{motorctl.__version__}.dist-info"
        assert top == {"motorctl", dist_info}, top
        assert whl.read(f"{dist_info}/top_level.txt").decode().split() == ["motorctl"]
    for room in ("protocol", "client", "daemon", "motion", "hal"):
        assert f"motorctl/{room}/__init__.py" in names
    # every module of every room, in every sub-package (found by setuptools, not listed)
    modules = {
        f"motorctl/{path.relative_to(ROOT).as_posix()}"
        for room in ("protocol", "client", "daemon", "motion", "hal")
        for path in (ROOT / room).rglob("*.py")
    }
    assert sorted(modules - set(names)) == []
    assert "motorctl/hal/layers/tmc/tmc5160.py" in modules
    assert "motorctl/daemon/config/model.py" in names and "motorctl/schema/__init__.py" in names
    assert not any(name.endswith((".pyc", "/tests/__init__.py")) for name in names)
    # the compiled dataclass methods, written by the wheel's build_py (setup.py) for its
    # interpreter (motorctl/dataclass_code.py)
    assert sorted(n for n in names if n.startswith("motorctl/dataclass_code.")) == [
        f"motorctl/dataclass_code.{sys.implementation.cache_tag}.bin",
        "motorctl/dataclass_code.py",
    ]
    # the compiled step core, built by the wheel's build; its sources stay out
    assert (
        [n for n in names if n.startswith("motorctl/motion/executors/_stepcore")]
        == [
            n
            for n in names
            if n.startswith("motorctl/motion/executors/_stepcore.") and n.endswith(".so")
        ]
        != []
    )
    assert not any(name.endswith((".c", ".h")) for name in names)

    # python-daemon first, then motorctl; uninstall motorctl.
    env.pip("install", "-q", "python-daemon")
    env.works(motorctl_installed=False, daemon_installed=True)
    env.pip("install", "-q", str(wheel))
    env.works(motorctl_installed=True, daemon_installed=True)
    env.mypy_sees_the_wheel(tmp_path)
    env.pip("uninstall", "-y", "-q", "motorctl")
    env.works(motorctl_installed=False, daemon_installed=True)

    # motorctl first, then python-daemon; uninstall python-daemon.
    env.pip("uninstall", "-y", "-q", "python-daemon")
    env.pip("install", "-q", str(wheel))
    env.works(motorctl_installed=True, daemon_installed=False)
    env.pip("install", "-q", "python-daemon")
    env.works(motorctl_installed=True, daemon_installed=True)
    env.pip("uninstall", "-y", "-q", "python-daemon")
    env.works(motorctl_installed=True, daemon_installed=False)
