"""The benches' floors (issue 36): bench/startup.py's program that imports a list of modules,
and bench/echo_peer.py's peer that makes the link's system calls a turn (``--as-link``),
answering over a real PTY as the echo peer does. Owners: the test's thread; the peers are
processes of their own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import serial

from bench.startup import LEAST, imports_code
from motorctl.protocol.codec import CodecOptions, IsReady, encode_command

ROOT = Path(__file__).resolve().parents[2]


def test_the_import_program_imports_each_module_it_has_and_skips_the_rest() -> None:
    code = imports_code(["json", "no_such_module_here", "tomllib"])
    wanted = "{'json', 'tomllib', 'no_such_module_here'}"
    code += f"\nimport sys; print(sorted({wanted} & set(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-I", "-c", code], capture_output=True, text=True, check=True, timeout=30
    )
    assert out.stdout.strip() == "['json', 'tomllib']"


def test_the_least_a_daemon_imports_is_imported_by_its_program() -> None:
    code = imports_code(LEAST) + f"\nimport sys; print(all(m in sys.modules for m in {LEAST!r}))"
    out = subprocess.run(
        [sys.executable, "-I", "-c", code], capture_output=True, text=True, check=True, timeout=30
    )
    assert out.stdout.strip() == "True"


@pytest.mark.parametrize("mode", [[], ["--as-link"]], ids=["echo", "as-link"])
def test_the_peers_answer_each_frame_over_a_pty(tmp_path: Path, mode: list[str]) -> None:
    link = tmp_path / "peer.pty"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    peer = subprocess.Popen(
        [sys.executable, str(ROOT / "bench" / "echo_peer.py"), str(link), *mode],
        stdout=subprocess.PIPE,
        env=env,
    )
    try:
        assert peer.stdout is not None
        assert peer.stdout.readline() == b"ready\n"
        frame = encode_command(IsReady(0), CodecOptions())
        with serial.Serial(str(link), 115200, timeout=5) as port:
            for _ in range(3):
                port.write(frame)
                assert port.read(5) == bytes([1, 1, 0, 0, 0x6B])
            port.write(frame * 2)  # two frames in one read: two answers
            assert port.read(10) == bytes([1, 1, 0, 0, 0x6B]) * 2
    finally:
        peer.kill()
        peer.wait()
