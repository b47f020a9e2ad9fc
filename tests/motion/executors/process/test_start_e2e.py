"""The step executor's interpreter (motion/executors/process/start.py) as motorctld starts it,
from a folder another user can write to: nothing there runs in it, it imports the daemon's own
``motorctl``, and ``ps`` names it. Real processes throughout.

The executor's first imports, after the interpreter's start-up (which no file in the current
folder can replace), were ``pickle``, ``signal``, ``socket`` and theirs (``_compat_pickle``,
``_pickle``, ``struct``, ``_struct``, ``selectors``, ``select``, ``array``, ``math``):
``python -c`` put the current folder first on the import path, so a ``pickle.py`` there ran
inside the executor, as root under ``sudo motorctld``. The folder here holds a booby-trapped
module for every name of the standard library and a ``motorctl`` package; each writes a
marker when imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import motorctl
from motorctl.motion.executors.process.start import COMM, TITLE, isolated_path
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess

#: A module that says it ran (``posix`` is built in: no file can stand in for it).
TRAP = "import posix\nposix.close(posix.open({marker!r}, posix.O_CREAT | posix.O_WRONLY, 0o644))\n"


def booby_trap(folder: Path, markers: Path) -> set[str]:
    """``folder`` with a trap for every module of the standard library and for ``motorctl``;
    the names trapped."""
    folder.mkdir()
    markers.mkdir()
    names = set(sys.stdlib_module_names)
    for name in names:
        (folder / f"{name}.py").write_text(TRAP.format(marker=str(markers / name)))
    (folder / "motorctl").mkdir()
    (folder / "motorctl" / "__init__.py").write_text(TRAP.format(marker=str(markers / "motorctl")))
    return names | {"motorctl"}


def console_script(folder: Path) -> Path:
    """A ``motorctld`` as pip installs it (a script in a ``bin`` folder of its own, whose
    folder is first on the daemon's import path, not the current folder)."""
    folder.mkdir()
    script = folder / "motorctld"
    script.write_text(
        f"#!{sys.executable}\nimport sys\nfrom motorctl.daemon.start.launch import main\n"
        "sys.exit(main())\n"
    )
    script.chmod(0o755)
    return script


def test_nothing_in_the_folder_motorctld_starts_in_runs_in_its_executor(tmp_path: Path) -> None:
    shared, markers = tmp_path / "shared", tmp_path / "markers"
    trapped = booby_trap(shared, markers)
    assert {"pickle", "_compat_pickle", "signal", "socket", "struct", "selectors"} <= trapped
    script = console_script(tmp_path / "bin")
    # motorctl found as the test found it (an installed checkout, or PYTHONPATH in a root)
    where = str(Path(motorctl.__file__).parent.parent)
    path = os.pathsep.join(p for p in (where, os.environ.get("PYTHONPATH")) if p)
    d = DaemonProcess(tmp_path, command=[str(script)], cwd=shared, env={"PYTHONPATH": path})
    try:
        d.start()
        executor = d.status()["executor"]
        assert executor["kind"] == "process" and executor["alive"]
        with d.client() as c:  # the executor steps: its modules are imported
            c.move_to(0, 100)
            c.wait_moved(0, 10_000)
            assert c.position(0) == 100
        pid = executor["pid"]
        # what ps shows: `ps -o args` reads cmdline, `ps -o comm` (and `ps -e`, top) comm
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        assert cmdline.rstrip(b"\0") == TITLE.encode(), cmdline[:200]
        assert Path(f"/proc/{pid}/comm").read_text() == f"{COMM}\n"
    finally:
        d.close()
        # (also when a trap broke the executor and so the daemon's start)
        ran = sorted(p.name for p in markers.iterdir())
        assert ran == [], f"imported from the folder motorctld was started in: {ran}"
    assert "not named in ps" not in d.stderr()


def test_the_import_path_loses_every_name_of_the_current_and_the_script_folder(
    tmp_path: Path,
) -> None:
    here, bin_ = tmp_path / "here", tmp_path / "bin"
    here.mkdir()
    script = console_script(bin_)
    (tmp_path / "alias").symlink_to(here)
    path = ["", ".", "lib", str(here), str(tmp_path / "alias"), str(bin_), "/usr/lib/python3"]
    assert isolated_path(path, str(here), str(script)) == ["/usr/lib/python3"]
    # -c's argv[0] names no file; a folder gone since the start has nothing to drop
    kept = [str(here), str(tmp_path / "alias"), str(bin_), "/usr/lib/python3"]
    assert isolated_path(path, None, "-c") == kept


def test_a_title_that_does_not_fit_is_said() -> None:
    """The command line keeps the interpreter's arguments, and the note says why (the
    executor logs it); the name is set all the same."""
    code = (
        "import sys; from motorctl.motion.executors.process.start import name_process; "
        "print(name_process('x' * 100000, 'short')); "
        "print(open('/proc/self/comm').read().strip())"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert out.returncode == 0, out.stderr
    note, comm = out.stdout.splitlines()
    assert note.startswith("command line: ") and "too few for the title" in note
    assert comm == "short"
