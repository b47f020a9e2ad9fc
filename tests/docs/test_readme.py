"""The README's client walkthrough, run literally as written against a real daemon on a PTY.

The daemon is started as `make run` starts it (embedded default, PTY `motorctl.pty` and
state in `.run/state` of the current directory); each line of the README's ```sh block under
"Trying it with the client" then runs in bash, in that directory, exactly as written. `.venv`
there is a symlink to the virtual environment running the tests.

Checked per line: the exit status is 0, or the one the line's comment names ("exit status
N"); a command that prints more than "ok" prints what its comment starts with; bytes the
comment quotes after "<-" are the bytes received.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess

README = REPO / "README.md"
LINE_TIMEOUT_S = 30.0


def walkthrough() -> list[tuple[str, str]]:
    """(command, comment) of each line of the client walkthrough's ```sh block."""
    text = README.read_text(encoding="utf-8")
    section = text.split("## Trying it with the client", 1)[1]
    block = section.split("```sh\n", 1)[1].split("```", 1)[0]
    lines = []
    for line in block.splitlines():
        command, _, comment = line.partition("  # ")
        lines.append((command.strip(), comment.strip()))
    return lines


def test_walkthrough_shape() -> None:
    lines = walkthrough()
    assert lines[0][0] == "export MOTORCTL_PORT=$PWD/motorctl.pty"
    assert len(lines) >= 10
    starts = (".venv/bin/motorctl ", ".venv/bin/motorctld ", "export ")
    assert all(command.startswith(starts) for command, _ in lines)


def test_readme_client_walkthrough_runs_as_written(tmp_path: Path) -> None:
    (tmp_path / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    daemon = DaemonProcess(tmp_path, state_dir=tmp_path / ".run" / "state")
    daemon.start()
    try:
        exports: list[str] = []
        for command, comment in walkthrough():
            if command.startswith("export "):
                exports.append(command)
                continue
            script = "; ".join(["set -u", *exports, command])
            run = subprocess.run(
                ["bash", "-c", script],
                cwd=tmp_path,
                capture_output=True,
                text=True,
                timeout=LINE_TIMEOUT_S,
            )
            where = f"README line {command!r} (# {comment})"
            wanted = re.search(r"exit status (\d+)", comment)
            status = int(wanted.group(1)) if wanted else 0
            output = (run.stdout + run.stderr).strip()
            assert run.returncode == status, f"{where}: exit {run.returncode}: {output}"
            if command.startswith(".venv/bin/motorctld --status"):
                status_doc = json.loads(run.stdout)
                assert status_doc["link"]["counters"]["frames_good"] > 0, where
                continue
            last = output.splitlines()[-1]
            if last != "ok":
                assert comment.startswith(last), f"{where}: printed {last!r}"
            for quoted in re.findall(r"<- ((?:[0-9a-f]{2} ?){5})", comment):
                assert f"<- {quoted.strip()}" in output, f"{where}: printed {output!r}"
    finally:
        daemon.close()
