"""What failed in one guest's run of the hardware tier, in a few lines (hwtest/run).

hwtest/run keeps each guest's console output and, when the guest failed, prints this digest of
it after the table of times: CI shows only a log's last lines, and one binding's failure used
to be scrolled away by the runs after it ("v2 API: FAILED (124)" and nothing more). From the
output of `pytest -v -ra` in the guest it takes: the FAILED/ERROR lines of pytest's summary;
a test that ran past its deadline (hwtest/deadline.py: faulthandler's "Timeout (h:mm:ss)!")
and the innermost frames of each of its threads; and, when the VM's own budget ran out
(run.sh: "run.sh: timeout"), how many tests had passed and which one was running or had
just finished. Pure text in, lines out; runs on the host (Python 3.9 and later).
Usage: python3 hwtest/digest.py LOG
"""

from __future__ import annotations

import re
import sys

FRAMES = 4  # innermost frames shown per thread
WIDTH = 300  # a summary line's characters shown
RESULT = re.compile(r" (PASSED|FAILED|ERROR|SKIPPED|XFAIL|XPASS) ")
NODE = re.compile(r"^(\S+::\S+)")
TIMEOUT = re.compile(r"Timeout \(\d+:\d\d:\d\d\)!")
THREAD = re.compile(r"^(Current thread|Thread) 0x[0-9a-f]+")


def digest(text: str) -> list[str]:
    out: list[str] = []
    passed = 0
    last = ""
    finished = False
    dumping = False
    frames = 0
    budget = False
    for line in text.splitlines():
        if line.startswith(("FAILED ", "ERROR ")):
            out.append(line[:WIDTH])
            continue
        node = NODE.match(line)
        if node:
            last = node.group(1)
            result = RESULT.search(line + " ")
            finished = result is not None
            passed += result is not None and result.group(1) == "PASSED"
        if TIMEOUT.search(line):
            out.append(f"{last} ran past its HWTEST_DEADLINE_S (hwtest/deadline.py); its threads:")
            dumping = True
        elif dumping and THREAD.match(line):
            out.append(line)
            frames = FRAMES
        elif dumping and frames > 0 and line.startswith("  File "):
            out.append(line)
            frames -= 1
        elif line.startswith("run.sh: timeout"):
            budget = True
    if budget:
        where = "" if not last else f" (after {last})" if finished else f"; running: {last}"
        out.append(f"the guest ran out of its GSIM_TIMEOUT after {passed} passed tests{where}")
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python3 hwtest/digest.py LOG", file=sys.stderr)
        return 2
    try:
        with open(argv[1], encoding="utf-8", errors="replace") as f:
            text = f.read()
    except OSError as exc:
        print(f"hwtest/digest.py: cannot read {argv[1]}: {exc.strerror}", file=sys.stderr)
        return 2
    for line in digest(text) or ["(nothing recognised: see the guest's output above)"]:
        print(f"  {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
