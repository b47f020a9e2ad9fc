"""motorctld's command line (daemon/start/main.py), in this process where it can be: the commands
that print and exit (--print-default-config, --check-config, --probe's step core lines,
--status without a daemon), the options that go only with --status, a start that cannot
begin said in one line. Serving itself: test_serve.py, test_serve_e2e.py."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.config import default_config_text
from motorctl.daemon.start.main import main
from motorctl.dataclass_code import CodeCache, Recorder, header
from tests.support import REPO
from tests.support.daemon_proc import StartDaemon, for_tests, run_on_pty

ROOT = REPO


def test_motorctld_prints_and_checks_the_default_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--print-default-config"]) == 0
    text = capsys.readouterr().out
    assert text == default_config_text()
    path = tmp_path / "motorctl.toml"
    path.write_text(text, encoding="utf-8")
    assert main(["--check-config", str(path)]) == 0
    assert capsys.readouterr().out == (f"{path}: OK (3 motors, 8 pins, a DC motor, backend mock)\n")
    path.write_text(text.replace("max_travel = 40000", "max_travel = 0", 1), encoding="utf-8")
    assert main(["--check-config", str(path)]) == 1
    assert "motors[0].homing.max_travel = 0: out of range" in capsys.readouterr().err


def test_a_dataclass_code_file_not_used_is_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The compiled dataclass methods motorctld's launch imported with (motorctl/
    dataclass_code.py): a file it could not use is said, whatever the command; one it used
    is not (its counts are logged at debug level once a serving start has read its config:
    tests/daemon/start/test_launch_startup.py)."""
    absent = CodeCache.load(tmp_path / "none.bin")
    assert main(["--print-default-config"], dataclass_code=absent) == 0
    err = capsys.readouterr().err
    assert "WARNING" in err and "dataclass code: 0 methods from" in err
    assert f"not used, {tmp_path / 'none.bin'} is absent" in err
    recorded = Recorder()
    payload = recorded.payload()  # a good file, of no method
    (tmp_path / "good.bin").write_bytes(header(payload) + payload)
    assert (
        main(["--print-default-config"], dataclass_code=CodeCache.load(tmp_path / "good.bin")) == 0
    )
    assert "dataclass code" not in capsys.readouterr().err


LAT0 = ("--latency-seconds", "0")


def _probe(tmp_path: Path, step_thread: str) -> subprocess.CompletedProcess[str]:
    config = tmp_path / "m.toml"
    config.write_text(
        for_tests(f'[step_thread]\n{step_thread}\n[[motors]]\nname = "a"\n', force=True)
    )
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--probe",
            "--config",
            str(config),
            *LAT0,
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def test_probe_says_which_step_core_would_run(tmp_path: Path) -> None:
    out = _probe(tmp_path, 'core = "auto"')
    assert out.returncode == 0, out.stderr
    assert (
        'step core:\n  [step_thread] core = "auto", executor = "process"\n'
        "  compiled core: built\n  lines for it: the simulated mechanics of the mock\n"
        "  runs: compiled\n"
    ) in out.stdout


def test_the_compiled_core_where_it_cannot_run_is_a_probe_problem_and_a_start_error(
    tmp_path: Path, motorctld: StartDaemon
) -> None:
    out = _probe(tmp_path, 'core = "compiled"\nexecutor = "thread"')
    assert out.returncode == 1
    assert "  runs: python (the thread executor runs the Python core)\n" in out.stdout
    assert 'PROBLEM: [step_thread] core = "compiled" runs in the process executor only' in (
        out.stdout
    )
    config = 'core = "compiled"\nexecutor = "thread"'
    text = for_tests(f'[step_thread]\n{config}\n[[motors]]\nname = "a"\n', force=True)
    with pytest.raises(RuntimeError, match="motorctld exited") as err:
        motorctld(text)
    assert '[step_thread] core = "compiled" runs in the process executor only' in str(err.value)
    # where it is not built: the start says so in one line, and exits (no traceback)
    text = for_tests('[step_thread]\ncore = "compiled"\n[[motors]]\nname = "a"\n', force=True)
    with pytest.raises(RuntimeError, match="motorctld exited") as err:
        motorctld(text, env={"MOTORCTL_STEPCORE": str(tmp_path / "missing.so")})
    said = str(err.value)
    assert 'error: the step executor cannot start: [step_thread] core = "compiled"' in said
    assert "the compiled step core is not built" in said and "Traceback" not in said


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--pty", "x", "--histogram"], "error: --histogram goes with --status"),
        (["--pty", "x", "--json"], "error: --json goes with --status"),
        (["--pty", "x", "--watch"], "error: --watch goes with --status"),
        (["--pty", "x", "--format", "openmetrics"], "error: --format goes with --status"),
        ([], "error: say where to serve: --pty PATH (a pseudo-terminal) or --port DEVICE"),
        (
            ["--status", "--watch", "--histogram"],
            "error: --watch shows the live view; --histogram, --json and --format go with a "
            "single --status",
        ),
        (
            ["--status", "--histogram", "--format", "openmetrics"],
            "error: --histogram goes with --format json",
        ),
    ],
)
def test_options_out_of_place_are_named_and_exit_2(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main([*argv, "--state-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == says


def test_status_without_a_daemon_says_where_it_looked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--status", "--state-dir", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: no daemon status at {tmp_path / 'status.sock'}: ")
    assert "Traceback" not in err


@contextlib.contextmanager
def _status_answered_once(path: Path, answer: bytes) -> Iterator[None]:
    """A status socket at ``path`` that answers one reader with ``answer``, then goes."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(str(path))
        server.listen(1)
        server.settimeout(60)

        def answer_once() -> None:
            conn, _ = server.accept()
            with conn:
                conn.recv(64)
                conn.sendall(answer)

        thread = threading.Thread(target=answer_once)
        thread.start()
        try:
            yield
        finally:
            thread.join(60)
    path.unlink()


def test_status_prints_what_the_socket_answers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--status is the document as the status socket gives it; an error document is an
    error (a socket that answers, but not with a status)."""
    path = tmp_path / "status.sock"
    for answer, code in ((b'{"motors": []}', 0), (b'{"error": "status unavailable"}', 1)):
        with _status_answered_once(path, answer):
            got = main(["--status", "--state-dir", str(tmp_path)])
        out, err = capsys.readouterr()
        assert got == code, err
        if code == 0:
            assert out == '{\n "motors": []\n}\n'
        else:
            assert "status unavailable" in err


def test_a_start_that_cannot_begin_is_one_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "missing.toml"
    args = ["--pty", str(tmp_path / "pty"), "--state-dir", str(tmp_path / "state")]
    assert main([*args, "--config", str(missing)]) == 1  # a ConfigError
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(missing) in err and err.count("\n") == 1
    config = tmp_path / "slow.toml"
    config.write_text(for_tests('[link]\ntimeout_ms = 1\n[[motors]]\nname = "a"\n'))
    assert main([*args, "--config", str(config), "--baud", "300"]) == 1  # ConfigError too
    err = capsys.readouterr().err
    assert err.startswith(f"error: {config}: ") and err.count("\n") == 1
    assert not (tmp_path / "pty").exists()  # nothing was opened


@pytest.mark.parametrize("status", [False, True], ids=["print-default-config", "status"])
def test_output_into_a_pipe_nobody_reads_ends_quietly(tmp_path: Path, status: bool) -> None:
    """motorctld --status | head: the reader is gone before the output (its end of the pipe
    is closed before motorctld starts): no BrokenPipeError traceback, SIGPIPE's status."""
    from motorctl.daemon.start.main import EXIT_PIPE

    args = ["--status", "--state-dir", str(tmp_path)] if status else ["--print-default-config"]
    answered = (
        _status_answered_once(tmp_path / "status.sock", b'{"motors": []}')
        if status
        else contextlib.nullcontext()
    )
    read, write = os.pipe()
    os.close(read)
    try:
        with answered:
            run = subprocess.run(
                [sys.executable, "-m", "motorctl.daemon.start.main", *args],
                stdout=write,
                stderr=subprocess.PIPE,
                text=True,
                timeout=60,
            )
    finally:
        os.close(write)
    assert (run.returncode, run.stderr) == (EXIT_PIPE, "")


def test_status_on_a_terminal_is_a_summary_and_in_a_pipe_the_document(
    motorctld: StartDaemon,
) -> None:
    """``motorctld --status`` as a person runs it (a real terminal: a pseudo-terminal) prints
    a screen of summary; into a pipe, as scripts read it, and with --json on the terminal,
    the whole document as JSON, as before."""
    d = motorctld()
    with d.client() as c:
        c.move_to(0, 300)
        c.wait_moved(0, 10_000)
    cmd = [
        sys.executable,
        "-m",
        "motorctl.daemon.start.main",
        "--status",
        "--state-dir",
        str(d.state_dir),
    ]
    code, out = run_on_pty(cmd)
    assert code == 0, out
    lines = out.splitlines()
    assert lines[0].startswith("motorctld ") and ": step executor process (pid " in lines[0]
    assert "  0 x: idle, position 300, speed 0 step/s" in lines
    assert any(
        line.startswith("real time: SCHED_FIFO not asked ([step_thread] priority = 0)")
        for line in lines
    )
    assert any(line.startswith("step timing: 300 step edges, late by p50 ") for line in lines)
    assert lines[-1] == "everything: motorctld --status --json (docs/status.md)"
    assert "{" not in out and len(lines) <= 24  # one screen
    piped = subprocess.run(cmd, capture_output=True, text=True, timeout=30, cwd=REPO)
    doc = json.loads(piped.stdout)
    assert doc["motors"][0]["position"] == 300 and doc["executor"]["realtime"]["refused"] == []
    code, out = run_on_pty([*cmd, "--json"])
    assert code == 0 and json.loads(out)["motors"][0]["position"] == 300


def _motorctld(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.main", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def test_a_pty_in_a_missing_folder_names_the_folder_and_the_fix(tmp_path: Path) -> None:
    """Not the PTY's lock file, an internal name: the folder the user gave, and what to do."""
    pty = tmp_path / "nonexistent" / "dir" / "x.pty"
    out = _motorctld("--pty", str(pty), "--state-dir", str(tmp_path / "state"))
    folder = pty.parent
    assert out.returncode == 1
    assert out.stderr == (
        f"error: --pty {pty}: the folder {folder} does not exist; create it "
        f"('mkdir -p {folder}') or give --pty a path in an existing folder\n"
    )
    assert not (tmp_path / "state").exists()  # said before anything was made
    assert not os.path.lexists("/nonexistent")
    out = _motorctld("--pty", "/nonexistent/dir/x.pty", "--state-dir", str(tmp_path / "state"))
    service = " ".join((REPO / "docs" / "service.md").read_text().split())
    assert f"`{out.stderr.strip()}`" in service  # as docs/service.md quotes it
    (tmp_path / "file").write_text("")
    out = _motorctld("--pty", str(tmp_path / "file" / "x.pty"), "--state-dir", str(tmp_path))
    assert out.returncode == 1 and f"{tmp_path / 'file'} is not a folder" in out.stderr


@pytest.mark.parametrize("baud", ["0", "-5", "fast"])
def test_a_baud_rate_that_is_none_is_refused_not_a_traceback(tmp_path: Path, baud: str) -> None:
    out = _motorctld("--pty", str(tmp_path / "x.pty"), "--baud", baud)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "motorctld: error: argument --baud: " in out.stderr
    assert "is not a baud rate" in out.stderr and "e.g. 115200" in out.stderr
    assert not (tmp_path / "x.pty").exists()


@pytest.mark.parametrize("columns", [None, "100", "37", "0", "wide", "-5"])
def test_the_help_is_as_wide_as_argparse_makes_it(
    columns: str | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--help at the width argparse's own formatter finds (through shutil, which a start
    no longer imports for it): from COLUMNS, else the terminal, else 80."""
    import argparse
    import shutil

    from motorctl.daemon.start.main import HelpFormatter, terminal_columns

    if columns is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", columns)
    assert terminal_columns() == shutil.get_terminal_size().columns
    ours, theirs = HelpFormatter("motorctld"), argparse.HelpFormatter("motorctld")
    assert ours._width == theirs._width and ours._max_help_position == theirs._max_help_position
    assert HelpFormatter("motorctld", width=50)._width == 50


@pytest.mark.parametrize(
    ("option", "given"),
    [
        ("--pty", ""),
        ("--pty", "."),
        ("--pty", "/"),
        ("--pty", ".."),
        ("--trace", ""),
        ("--trace", "sub/.."),
        ("--trace", "logs/"),
    ],
)
def test_a_pty_or_trace_path_that_names_a_folder_is_refused_before_anything_is_made(
    tmp_path: Path, option: str, given: str
) -> None:
    """``--pty ''`` or ``--trace logs/`` name no file: the PTY's lock name could not be
    made from ``''`` (a ValueError traceback), and the folder they name (the current one,
    ``logs``) was set aside as in the way of the daemon's file (``Path`` forgets the
    ``/``). A usage error, nothing touched."""
    work = tmp_path / "work"
    (work / "logs").mkdir(parents=True)
    (work / "sub").mkdir()
    args = ["--state-dir", str(tmp_path / "state")]
    if option == "--trace":
        args += ["--pty", str(tmp_path / "x.pty")]
    out = subprocess.run(
        [sys.executable, "-m", "motorctl.daemon.start.main", *args, option, given],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=work,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert out.stderr.endswith(
        f"motorctld: error: argument {option}: {given!r} names a folder, not a file; give "
        "the path of the file to make in it (e.g. ./motorctl.pty, /tmp/link.pcapng)\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]  # no state, no PTY
    assert sorted(p.name for p in work.iterdir()) == ["logs", "sub"]


@pytest.mark.parametrize("option", ["--port", "--config", "--check-config"])
def test_an_empty_path_is_a_usage_error(tmp_path: Path, option: str) -> None:
    """``--port ''`` served a device of no name, waiting for ever for it to appear;
    ``--check-config ''`` was taken for no option (``say where to serve``)."""
    out = _motorctld(option, "", "--state-dir", str(tmp_path / "state"))
    assert out.returncode == 2, out.stderr
    assert f"motorctld: error: argument {option}: '' is no path; give one\n" in out.stderr
    assert not (tmp_path / "state").exists()


@pytest.mark.parametrize("seconds", ["inf", "nan", "-1", "1e9", "soon"])
def test_a_latency_measurement_that_cannot_end_is_refused(seconds: str) -> None:
    """``--probe --latency-seconds inf`` measured for ever, ``nan`` failed in a thread with
    a traceback; out of 0..3600 (or no number) is a usage error, said before anything."""
    out = _motorctld("--probe", "--latency-seconds", seconds)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert (
        f"motorctld: error: argument --latency-seconds: '{seconds}' is not a number of "
        "seconds in 0..3600 (0 skips it)"
    ) in out.stderr
    assert out.stdout == ""


def test_status_says_how_to_reach_a_daemon_that_does_not_answer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No socket, a state directory that is a file, something else at status.sock (a
    stale socket nobody serves, a file): the path, why, and what to do."""
    fix = (
        "no motorctld serves its status there; start it, or give --state-dir the state "
        "directory it runs with (default /run/motorctl)\n"
    )
    (tmp_path / "file").write_text("")
    (tmp_path / "dir").mkdir()
    (tmp_path / "dir" / "status.sock").write_text("")
    stale = tmp_path / "stale"
    stale.mkdir()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as gone:
        gone.bind(str(stale / "status.sock"))  # bound, never listening: refused
        for state_dir, why in (
            (tmp_path / "none", "No such file or directory"),
            (tmp_path / "file", "Not a directory"),
            (tmp_path / "dir", "Connection refused"),
            (stale, "Connection refused"),
        ):
            assert main(["--status", "--state-dir", str(state_dir)]) == 1
            err = capsys.readouterr().err
            assert err == f"error: no daemon status at {state_dir / 'status.sock'}: {why}: {fix}"


def test_a_state_directory_that_cannot_be_made_names_what_named_it(tmp_path: Path) -> None:
    """A file where the state directory goes: said as such (not mkdir's "File exists"),
    and the fix names what gave the path: --state-dir, or [state] directory in the
    config (before, both said "pass --state-dir")."""
    (tmp_path / "file").write_text("")
    pty = str(tmp_path / "x.pty")
    out = _motorctld("--pty", pty, "--state-dir", str(tmp_path / "file"))
    assert out.returncode == 1, out.stderr
    assert out.stderr == (
        f"error: cannot create state directory {tmp_path / 'file'}: something that is not "
        "a directory is there; give --state-dir a writable directory\n"
    )
    config = tmp_path / "m.toml"
    text = f'[state]\ndirectory = "{tmp_path / "file"}"\n[[motors]]\nname = "a"\n'
    config.write_text(for_tests(text))
    out = _motorctld("--pty", pty, "--state-dir", str(tmp_path / "s"), "--config", str(config))
    assert out.returncode == 1, out.stderr
    assert out.stderr == (
        f"error: cannot create state directory {tmp_path / 'file'}: something that is not "
        f"a directory is there; give [state] directory in {config} a writable directory\n"
    )
    assert not os.path.lexists(pty)


def test_a_state_directory_too_long_for_the_status_socket_is_said_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A Unix socket's path holds 107 bytes: a longer --state-dir failed at the status
    socket, after the state was restored and written, naming no fix."""
    from motorctl.daemon.state.files import BIND_SUFFIX, SOCKET_PATH_MAX

    fits = tmp_path / ("d" * (SOCKET_PATH_MAX - BIND_SUFFIX - len(str(tmp_path)) - 1))
    assert len(str(fits)) + BIND_SUFFIX == SOCKET_PATH_MAX
    long = Path(f"{fits}x")
    pty = tmp_path / "x.pty"
    assert main(["--pty", str(pty), "--state-dir", str(long)]) == 1
    assert capsys.readouterr().err == (
        f"error: --state-dir {long}: too long for the status socket in it (a Unix socket's "
        f"path holds at most 107 bytes, 108 here); give a shorter path\n"
    )
    assert not long.exists() and not pty.exists()
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:  # the longest that fits
        fits.mkdir()
        private = fits / ".sabcdefgh"
        private.mkdir()
        sock.bind(str(private / "s"))
