"""The status document of a real motorctld (a process on a real PTY), as its readers see
it: the subscribe stream follows a move as it happens, --status --format prometheus and
openmetrics parse and carry the expected names, types and values, the monitor draws the
daemon's state (motorctl monitor --once, motorctld --status --watch off a terminal)."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time

import pytest

from motorctl import __version__
from motorctl.daemon.status.reader import subscribe
from tests.daemon.status.test_metrics import parse_om, parse_prometheus
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess, StartDaemon
from tests.support.wait import WAIT_S

#: the conformance suite: make test-dspin runs it on docs/examples/dspin.toml's chips too
pytestmark = pytest.mark.conformance

ROOT = REPO


@pytest.fixture
def daemon(motorctld: StartDaemon) -> DaemonProcess:
    return motorctld()  # the embedded default: mock world, pins, DC motor


def run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT
    )


def test_the_subscribe_stream_follows_a_move(daemon: DaemonProcess) -> None:
    """Updates come as the state changes: the motor seen moving, then at rest at its
    target, each as one JSON object per line."""
    stream = subscribe(daemon.state_dir / "status.sock", period_s=0.05)
    first = next(stream)
    assert first["motors"][0]["state"] == "idle" and first["motors"][0]["position"] == 0
    with daemon.client() as c:
        c.move_to(0, 600, 250)  # 1000 step/s: 0.6 s, a dozen updates at 50 ms
        states: list[tuple[str, int, float]] = []
        deadline = time.monotonic() + WAIT_S
        for doc in stream:  # an update at least every heartbeat: the loop is bounded
            m = doc["motors"][0]
            states.append((m["state"], m["position"], m["speed"]))
            if m["state"] == "idle" and m["position"] == 600:
                break
            assert time.monotonic() < deadline, states
        stream.close()
    moving = [s for s in states if s[0] == "moving"]
    assert len(moving) >= 3, states  # seen on the way, not only before and after
    assert len({p for _, p, _ in moving}) >= 3 and max(v for *_, v in moving) > 0
    assert states[-1] == ("idle", 600, 0.0)
    recent = doc["link"]["recent"]
    assert (
        recent[-1]["command"] == "MoveTo(motor=0, dir=up, pos=600, speed=250, acc=0, dec=0)"
        and recent[-1]["result"] == "ok"
    )


def test_metrics_of_a_live_daemon(daemon: DaemonProcess) -> None:
    """Each format of a live daemon's metrics, parsed by prometheus_client's parser of that
    format: the expected names, values, types; ``motorctl_up 0`` without a daemon."""
    with daemon.client() as c:
        c.move_to(1, 200, 250)
        c.wait_moved(1, 20_000)
        c.set_pin(2, True)
        # 60 s: both formats' --status runs (two interpreter starts each) see it still running
        # on a loaded machine (5 s was not always enough beside other work)
        c.dc_move(True, 60_000, False)
        with pytest.raises(Exception, match="E2"):
            c.move_to(7, 1)
    for fmt in ("prometheus", "openmetrics"):
        check_metrics(daemon, fmt)


def check_metrics(daemon: DaemonProcess, fmt: str) -> None:
    parse = parse_prometheus if fmt == "prometheus" else parse_om
    out = run(
        "motorctl.daemon.start.main",
        "--status",
        "--format",
        fmt,
        "--state-dir",
        str(daemon.state_dir),
    )
    assert out.returncode == 0, out.stderr
    families = {f.name: f for f in parse(out.stdout)}
    assert all(name.startswith("motorctl_") for name in families)
    # the step families where the daemon times steps (a step executor: STEP/DIR motors);
    # motors on driver chips that run their own ramps (the dSPIN world) have none
    stepping = {"motorctl_steps", "motorctl_step_lateness_seconds"}
    stepped = daemon.status()["executor"]["kind"] != "none"
    assert stepping & set(families) == (stepping if stepped else set()), fmt
    assert {
        "motorctl_up",
        "motorctl_motor_position_steps",
        "motorctl_motor_state",
        "motorctl_link_frames",
        "motorctl_link_error_responses",
        "motorctl_pin_level",
        "motorctl_dc_state",
        "motorctl_executor_alive",
        "motorctl_state_writes",
        "motorctl_link_processing_seconds",
    } <= set(families), fmt
    counters = ["motorctl_link_frames", "motorctl_link_error_responses"]
    summaries = ["motorctl_link_processing_seconds"]
    if stepped:
        counters.append("motorctl_steps")
        summaries.append("motorctl_step_lateness_seconds")
    for name in counters:
        assert families[name].type == "counter", (fmt, name)
    for name in summaries:
        assert families[name].type == "summary", (fmt, name)
        assert {s.name for s in families[name].samples} >= {name + "_count", name + "_sum"}

    def value(metric: str, sample: str | None = None, **labels: str) -> float:
        found = [
            s.value
            for s in families[metric].samples
            if (sample is None or s.name == sample)
            and all(s.labels.get(k) == v for k, v in labels.items())
        ]
        assert len(found) == 1, (fmt, metric, labels, families[metric].samples)
        return float(found[0])

    build = "motorctl_build" if fmt == "openmetrics" else "motorctl_build_info"
    assert value(build, version=__version__) == 1
    assert value("motorctl_up") == 1
    assert value("motorctl_motor_position_steps", motor="1", name="y") == 200
    assert value("motorctl_motor_state", motor="1", state="idle") == 1
    assert value("motorctl_pin_level", pin="2", mode="output") == 1
    assert value("motorctl_pin_level", pin="6", mode="input") == 1  # wired to output 2
    assert value("motorctl_dc_state", state="forward") == 1
    assert value("motorctl_link_error_responses", code="E2") == 1
    assert value("motorctl_link_frames") >= 5
    if stepped:
        assert value("motorctl_steps") >= 200
        assert value("motorctl_step_lateness_seconds", "motorctl_step_lateness_seconds_sum") > 0
    assert value("motorctl_executor_alive") == 1
    assert value("motorctl_trace_enabled") == 0
    gone = run(
        "motorctl.daemon.start.main",
        "--status",
        "--format",
        fmt,
        "--state-dir",
        str(daemon.workdir / "nowhere"),
    )
    assert gone.returncode == 1 and "no daemon status at" in gone.stderr
    assert [(s.name, s.value) for f in parse(gone.stdout) for s in f.samples] == [
        ("motorctl_up", 0)
    ]


def test_the_monitor_draws_the_daemon(daemon: DaemonProcess) -> None:
    with daemon.client() as c:
        c.set_pin(1, True)
        c.move_to(2, 150, 250)
        c.wait_moved(2, 20_000)
        with pytest.raises(Exception, match="E2"):
            c.move_to(9, 3)
    env = {**os.environ, "COLUMNS": "160"}
    once = subprocess.run(
        [
            sys.executable,
            "-m",
            "motorctl.client.cli",
            "monitor",
            "--once",
            "--state-dir",
            str(daemon.state_dir),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        env=env,
    )
    assert once.returncode == 0, once.stderr
    text = once.stdout
    z = next(line for line in text.splitlines() if line.split()[:2] == ["2", "z"])
    assert z.split()[2:4] == ["idle", "150"]
    kind = daemon.status()["executor"]["kind"]  # the step executor ("none" on dSPINs)
    assert f"executor {kind}" in text and "alive" in text
    assert "pins 0:out L  1:out H  2:out L  3:out L  4:in L  5:in H" in text
    assert "DC motor coast" in text  # never run: the bridge as it starts
    assert "MoveTo(motor=9, dir=up, pos=3, speed=0, acc=0, dec=0)" in text
    assert "E2 Invalid Address" in text
    # --status --watch off a terminal: one drawing per update until interrupted
    watch = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "motorctl.daemon.start.main",
            "--status",
            "--watch",
            "--period",
            "50",
            "--state-dir",
            str(daemon.state_dir),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
        env=env,
    )
    assert watch.stdout is not None
    seen = b""
    sel = selectors.DefaultSelector()
    sel.register(watch.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + WAIT_S
    try:
        while b"last frames" not in seen:
            left = deadline - time.monotonic()
            assert left > 0 and sel.select(left), seen
            chunk = os.read(watch.stdout.fileno(), 65536)
            assert chunk, watch.stderr.read() if watch.stderr else b""
            seen += chunk
        watch.send_signal(signal.SIGINT)
        assert watch.wait(WAIT_S) == 0
    finally:
        sel.close()
        if watch.poll() is None:
            watch.kill()
            watch.wait(10)
        watch.stdout.close()
        if watch.stderr is not None:
            watch.stderr.close()
    assert b"idle" in seen and b"E2 Invalid Address" in seen
