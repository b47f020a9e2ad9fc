"""hwtest/digest.py: the few lines hwtest/run repeats at its end for a guest that failed."""

from __future__ import annotations

import subprocess
import sys

from hwtest.digest import FRAMES, digest
from tests.support import REPO

PASSED = "tests/contract/test_contract.py::test_{} PASSED                [ {}%]"


def test_failed_and_errored_tests_are_listed() -> None:
    log = "\n".join(
        [
            PASSED.format("a", 2),
            "hwtest/test_daemon.py::test_b FAILED                 [ 5%]",
            "=========================== short test summary info ============================",
            "FAILED hwtest/test_daemon.py::test_b - AssertionError: timed out waiting for x",
            "ERROR hwtest/test_daemon.py::test_c - RuntimeError: motorctld not ready",
            "=================== 1 failed, 1 passed, 1 error in 9.1s ===================",
        ]
    )
    assert digest(log) == [
        "FAILED hwtest/test_daemon.py::test_b - AssertionError: timed out waiting for x",
        "ERROR hwtest/test_daemon.py::test_c - RuntimeError: motorctld not ready",
    ]


def test_a_stuck_test_shows_its_innermost_frames_per_thread() -> None:
    frames = [f'  File "/x/f{i}.py", line {i} in f{i}' for i in range(FRAMES + 3)]
    log = "\n".join(
        [
            PASSED.format("a", 2),
            "hwtest/test_daemon.py::test_b Timeout (0:04:00)!",
            "Thread 0x00007f0de3fff6c0 (most recent call first):",
            *frames[:2],
            "",
            "Current thread 0x00007f0deb23ab80 (most recent call first):",
            *frames,
        ]
    )
    assert digest(log) == [
        "hwtest/test_daemon.py::test_b ran past its HWTEST_DEADLINE_S (hwtest/deadline.py);"
        " its threads:",
        "Thread 0x00007f0de3fff6c0 (most recent call first):",
        *frames[:2],
        "Current thread 0x00007f0deb23ab80 (most recent call first):",
        *frames[:FRAMES],
    ]


def test_the_budget_running_out_says_which_test_ran_or_had_just_finished() -> None:
    running = "\n".join(
        [PASSED.format("a", 2), PASSED.format("b", 5), "hwtest/test_x.py::test_c ", ""]
    )
    assert digest(running + "run.sh: timeout\n") == [
        "the guest ran out of its GSIM_TIMEOUT after 2 passed tests; running: "
        "hwtest/test_x.py::test_c"
    ]
    after = "\n".join([PASSED.format("a", 2), "run.sh: timeout"])
    assert digest(after) == [
        "the guest ran out of its GSIM_TIMEOUT after 1 passed tests "
        "(after tests/contract/test_contract.py::test_a)"
    ]
    assert digest("booting\nrun.sh: timeout\n") == [
        "the guest ran out of its GSIM_TIMEOUT after 0 passed tests"
    ]


def test_the_script_prints_the_digest_and_names_what_it_cannot_read(tmp_path: object) -> None:
    from pathlib import Path

    log = Path(str(tmp_path)) / "guest.log"
    log.write_text("FAILED a::b - x\n")
    script = str(REPO / "hwtest" / "digest.py")
    out = subprocess.run([sys.executable, script, str(log)], capture_output=True, text=True)
    assert (out.returncode, out.stdout) == (0, "  FAILED a::b - x\n")
    log.write_text("booted, then nothing\n")
    out = subprocess.run([sys.executable, script, str(log)], capture_output=True, text=True)
    assert out.stdout == "  (nothing recognised: see the guest's output above)\n"
    out = subprocess.run(
        [sys.executable, script, str(log) + ".gone"], capture_output=True, text=True
    )
    assert out.returncode == 2 and "cannot read" in out.stderr and ".gone" in out.stderr
