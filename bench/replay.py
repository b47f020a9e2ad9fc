"""The replay's acceptance, 20-fold (docs/trace.md, "Replay"; issue 26).

A session is recorded by ``motorctld --trace`` as a user makes one with the motorctl CLI (a
process per command, opening the port each time): the README's client walkthrough, then a
MoveTo of 8000 stopped hard midway (``motorctl stop 0 --hard``) and one back stopped softly
(``motorctl stop 0``), with a position read while each moves and after each stop. Then:

- 20 paced replays and 20 ``--fast`` replays, each against a fresh daemon with the same
  config (the embedded default), must pass: exit 0, no difference;
- three replays against a fresh daemon behind a forwarder that changes one answer
  (tests/support/tamper.py) must fail (exit 1) with exactly one DIFF, naming that frame: the
  E2 of ``moveto 5 0`` answered E1; the position after the hard stop, and the one after the
  soft stop, moved by more than the whole range the clean replays allowed for it.

Printed: passes, exit statuses, the pacing error (p50/p99/max over the runs), the answers
within tolerance and how far the timed ones were from the recording against what was
allowed, each replay daemon's step slide (``motors[0].timing.slid_ms``: how far its motor
fell behind plan, the device timing the tolerance absorbs), and the tampered runs' DIFF
lines. ``--json FILE`` writes the figures. Daemons start as a user starts them (real-time
priority as root), with RT throttling off for the run (bench/__init__.py).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench import rt_throttling_off
from motorctl.client.trace import analyse, one_link
from motorctl.protocol.codec import ErrorCode, GetAbsPos, MoveTo, StopMove, WaitMoved
from tests.docs.test_readme import walkthrough
from tests.support.daemon_proc import DaemonProcess
from tests.support.tamper import Rewrite, Tamper, other_error, position_off

ROOT = Path(__file__).resolve().parent.parent
MOTORCTL = [sys.executable, "-m", "motorctl.client.cli"]
#: the part after the README: (command, pause after it, s): a host's own timing
STOPS: list[tuple[list[str], float]] = [
    (["moveto", "0", "8000"], 0.6),
    (["pos", "0"], 0.3),
    (["stop", "0", "--hard"], 0.0),
    (["pos", "0"], 0.0),
    (["ready", "0"], 0.0),
    (["moveto", "0", "200"], 0.7),
    (["pos", "0"], 0.0),
    (["stop", "0"], 0.0),
    (["wait", "0"], 0.0),
    (["pos", "0"], 0.0),
]


RECORDED: dict[str, Any] = {}  # the recording daemon's figures


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))] if ordered else 0.0


def cli(port: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MOTORCTL_PORT": str(port)}
    return subprocess.run(
        [*MOTORCTL, *args], env=env, capture_output=True, text=True, cwd=ROOT, timeout=120
    )


def record(work: Path) -> Path:
    """The session, recorded by a daemon's own trace, as the CLI makes it."""
    trace = work / "session.pcapng"
    (work / "rec").mkdir()
    d = DaemonProcess(work / "rec", extra=["--trace", str(trace)], as_user=True).start()
    try:
        for line, _ in walkthrough():
            if not line.startswith(".venv/bin/motorctl "):
                continue  # the export, and motorctld --status (no link traffic)
            args = line.split()[1:]
            run = cli(d.pty, *args)
            if run.returncode not in (0, 1):
                raise RuntimeError(f"{line}: {run.stderr}")
        for args, pause in STOPS:
            run = cli(d.pty, *args)
            if run.returncode != 0:
                raise RuntimeError(f"motorctl {' '.join(args)}: {run.stdout}{run.stderr}")
            time.sleep(pause)  # the host's own pause: what a replay must keep
        RECORDED["slid_ms"] = d.status()["motors"][0].get("timing", {}).get("slid_ms")
    finally:
        d.close()
    return trace


def frames_of_interest(trace: Path) -> dict[str, int]:
    """Frame numbers: the E2 of ``moveto 5 0``, the position read after the hard stop and
    the one read after the soft stop's WaitMoved."""
    _, link, info = one_link([trace], None, None, None)
    conv = analyse(link.records, info)
    out: dict[str, int] = {}
    after = ""
    for f in conv.frames:
        cmd = f.command
        if isinstance(cmd, MoveTo) and cmd.motor == 5:
            out["error_code"] = f.number
        elif isinstance(cmd, StopMove):
            after = "hard_stop_position" if cmd.hard else "soft"
        elif isinstance(cmd, WaitMoved) and after == "soft":
            after = "soft_stop_position"
        elif isinstance(cmd, GetAbsPos) and after.endswith("_position"):
            out[after], after = f.number, ""
    return out


def replay(
    work: Path, trace: Path, fast: bool, tamper: tuple[int, Rewrite] | None = None
) -> dict[str, Any]:
    """One replay against a fresh daemon (behind a tamper when given): its JSON report, exit
    status and the daemon's slide."""
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    d = DaemonProcess(work, as_user=True).start()
    t: Tamper | None = None
    try:
        port = str(d.pty)
        if tamper is not None:
            t = Tamper(d.pty, *tamper).start()
            port = t.port
        args = ["replay", str(trace), "--port", port, "--json"] + (["--fast"] if fast else [])
        run = subprocess.run(
            [*MOTORCTL, *args], capture_output=True, text=True, cwd=ROOT, timeout=300
        )
        timing = d.status()["motors"][0].get("timing", {})
    finally:
        if t is not None:
            t.close()
        d.close()
    doc: dict[str, Any] = json.loads(run.stdout) if run.stdout.startswith("{") else {}
    doc["exit"] = run.returncode
    doc["stderr"] = run.stderr.strip()
    doc["slid_ms"] = timing.get("slid_ms")
    return doc


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    pacing = [r["pacing"] for r in runs if r.get("pacing")]
    timed: dict[int, list[tuple[int, int, int]]] = {}
    for r in runs:
        for v in r.get("verdicts", []):
            if v["result"] == "tolerated" and v["allowed"] is not None and v["off"] is not None:
                lo, hi = v["allowed"]
                timed.setdefault(v["frame"], []).append((v["off"], lo, hi))
    return {
        "runs": len(runs),
        "passed": sum(1 for r in runs if r["exit"] == 0),
        "exit_statuses": sorted({r["exit"] for r in runs}),
        "pacing_p50_ms": round(pct([p["p50_ms"] for p in pacing], 50), 3),
        "pacing_p99_ms_worst": max((p["p99_ms"] for p in pacing), default=0),
        "pacing_max_ms_worst": max((p["max_ms"] for p in pacing), default=0),
        "tolerated_per_run": sorted({r.get("tolerated", 0) for r in runs}),
        "slid_ms_max": max((r["slid_ms"] or 0 for r in runs), default=0),
        "positions": {
            str(frame): {
                "max_off": max(abs(o) for o, _, _ in xs),
                "narrowest_range": min(hi - lo for _, lo, hi in xs),
                "widest_range": max(hi - lo for _, lo, hi in xs),
            }
            for frame, xs in sorted(timed.items())
        },
        "slid_ms_per_run": [r["slid_ms"] for r in runs],
        "failures": [
            {
                "run": i,
                "exit": r["exit"],
                "slid_ms": r["slid_ms"],
                "stderr": r["stderr"],
                "diffs": [v for v in r.get("verdicts", []) if v["result"] != "tolerated"],
            }
            for i, r in enumerate(runs)
            if r["exit"] != 0
        ],
    }


def tampered(
    work: Path, trace: Path, frames: dict[str, int], paced: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Replays behind a forwarder that changes one answer: each must name that frame."""
    widest: dict[int, int] = {}
    for r in paced:
        for v in r.get("verdicts", []):
            if v.get("allowed"):
                lo, hi = v["allowed"]
                widest[v["frame"]] = max(widest.get(v["frame"], 0), hi - lo)
    cases: list[tuple[str, int, Rewrite, str]] = [
        (
            "error_code",
            frames["error_code"],
            other_error(ErrorCode.INVALID_COMMAND),
            "E2 answered E1",
        )
    ]
    for key in ("hard_stop_position", "soft_stop_position"):
        n = frames[key]
        off = widest.get(n, 0) + 50
        cases.append((key, n, position_off(off), f"position moved by {off} steps"))
    out = []
    for name, n, rewrite, what in cases:
        doc = replay(work / f"tamper-{name}", trace, False, (n, rewrite))
        diffs = [v for v in doc.get("verdicts", []) if v["result"] == "differs"]
        out.append(
            {
                "case": name,
                "frame": n,
                "change": what,
                "exit": doc["exit"],
                "diff_frames": [v["frame"] for v in diffs],
                "caught": doc["exit"] == 1 and [v["frame"] for v in diffs] == [n],
                "diff_lines": [
                    f"frame #{v['frame']} {v['command']}: recorded {v['recorded']}, replayed "
                    f"{v['replayed']} ({v['why']})"
                    for v in diffs
                ],
            }
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=20, help="replays of each kind (default 20)")
    ap.add_argument("--json", metavar="FILE", help="write the figures here")
    ap.add_argument("--keep", action="store_true", help="keep the work folder (printed)")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="motorctl-bench-replay-"))
    figures: dict[str, Any] = {}
    try:
        with rt_throttling_off() as before:
            figures["rt_runtime_before"] = before
            trace = record(work)
            frames = frames_of_interest(trace)
            figures["frames_of_interest"] = frames
            figures["recording_slid_ms"] = RECORDED.get("slid_ms")
            figures["load_before"] = round(os.getloadavg()[0], 2)
            paced = [replay(work / f"paced-{i}", trace, False) for i in range(args.n)]
            fast = [replay(work / f"fast-{i}", trace, True) for i in range(args.n)]
            figures["paced"] = summarise(paced)
            figures["fast"] = summarise(fast)
            figures["tampered"] = tampered(work, trace, frames, paced)
            figures["load_after"] = round(os.getloadavg()[0], 2)
    finally:
        if args.keep:
            print(f"work folder: {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    report(figures)
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1) + "\n")
    ok = (
        figures["paced"]["passed"] == args.n
        and figures["fast"]["passed"] == args.n
        and all(t["caught"] for t in figures["tampered"])
    )
    return 0 if ok else 1


def report(fig: dict[str, Any]) -> None:
    print(
        f"load average {fig['load_before']} before, {fig['load_after']} after; the recording "
        f"daemon's motor slid {fig['recording_slid_ms']} ms"
    )
    for kind in ("paced", "fast"):
        s = fig[kind]
        print(
            f"{kind}: {s['passed']}/{s['runs']} passed (exit statuses {s['exit_statuses']}); "
            f"pacing error p50 {s['pacing_p50_ms']} ms, worst p99 {s['pacing_p99_ms_worst']} "
            f"ms, worst max {s['pacing_max_ms_worst']} ms; answers within tolerance per run "
            f"{s['tolerated_per_run']}; replay daemons' slide at most {s['slid_ms_max']} ms"
        )
        for frame, p in s["positions"].items():
            print(
                f"  frame #{frame}: at most {p['max_off']} steps from the recording; allowed "
                f"range {p['narrowest_range']}..{p['widest_range']} steps wide"
            )
        slid = sorted(x or 0 for x in s["slid_ms_per_run"])
        print(f"  replay daemons' slide per run, ms: {', '.join(f'{x:.0f}' for x in slid)}")
        for f in s["failures"]:
            print(
                f"  FAILED run {f['run']} exit {f['exit']} (its daemon slid {f['slid_ms']} ms)"
                f"{': ' + f['stderr'] if f['stderr'] else ''}"
            )
            for v in f["diffs"]:
                print(f"    {v['result']}: frame #{v['frame']} {v['command']}: {v['why']}")
    for t in fig["tampered"]:
        print(
            f"tampered {t['case']} (frame #{t['frame']}: {t['change']}): exit {t['exit']}, "
            f"DIFF frames {t['diff_frames']}: {'caught' if t['caught'] else 'NOT CAUGHT'}"
        )
        for line in t["diff_lines"]:
            print(f"  DIFF {line}")


if __name__ == "__main__":
    sys.exit(main())
