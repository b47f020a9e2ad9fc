"""Trace files as users meet them, on real recordings (motorctld --trace, motorctl tap):
Wireshark's view through the Lua dissector (tshark), mergecap'd files, rotated parts with
one missing, pcap files, and damaged files: every truncation point, byte flips, through
``motorctl trace`` and ``motorctl replay`` alike (docs/trace.md).

tshark, mergecap and editcap come from Debian's tshark package (``make test`` installs it
when run as root); without them the tests that need them skip, saying so.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from motorctl.client import cli, dissector, replay, trace
from motorctl.client.client import Client
from motorctl.client.recording import TraceFileError, links_of, load, read
from motorctl.protocol.capture.format import LINKTYPE_USER0, Direction
from motorctl.protocol.capture.reader import parse
from motorctl.protocol.codec import (
    CodecOptions,
    GetAbsPos,
    IsReady,
    MoveTo,
    SetPin,
    encode_command,
)
from motorctl.protocol.crc import CATALOGUE
from tests.client.test_trace_e2e import (
    CONFIG,
    motorctl,
    pty_pair,
    read_exactly,
    session,
    start_tap,
    stop_tap,
    subdir,
)
from tests.support import REPO
from tests.support.daemon_proc import DaemonProcess

OPTS = CodecOptions()
TEMPLATE = REPO / "client" / "wireshark" / "motorctl.lua.in"
TSHARK = shutil.which("tshark")
MERGECAP = shutil.which("mergecap")
needs_tshark = pytest.mark.skipif(
    TSHARK is None,
    reason="TSHARK IS MISSING, so the Wireshark dissector's tests did NOT run: apt-get install "
    "tshark (make test installs it when run as root)",
)
needs_mergecap = pytest.mark.skipif(
    MERGECAP is None,
    reason="MERGECAP IS MISSING, so the merged-file tests did NOT run: apt-get install tshark "
    "(it brings mergecap; make test installs it when run as root)",
)
FIELDS = (
    "frame.number",
    "motorctl.kind",
    "motorctl.command",
    "motorctl.motor",
    "motorctl.position",
    "motorctl.frame",
    "motorctl.error_name",
    "motorctl.frame_error",
)


def more(c: Client) -> None:
    """Beyond the walkthrough: a frame in two writes within the gap, two frames in one write,
    a run and a hard stop, pin modes, home."""
    frame = encode_command(GetAbsPos(0), OPTS)
    c.send_bytes(frame[:3])
    c.send_bytes(frame[3:])
    assert c.read_response().ack
    c.send_bytes(encode_command(IsReady(0), OPTS) + encode_command(IsReady(1), OPTS))
    assert c.read_response().ack and c.read_response().ack
    c.move(1, False, speed=100)
    c.stop(1, hard=True)
    c.config_pin(3, True)
    c.save_home(0)
    c.go_home(0)
    c.wait_moved(0, 5000)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A session recorded by motorctld's own trace."""
    work = tmp_path_factory.mktemp("rec")
    trace = work / "session.pcapng"
    d = DaemonProcess(work, CONFIG, extra=["--trace", str(trace)]).start()
    try:
        with d.client() as c:
            session(c)
            more(c)
    finally:
        d.close()
    assert d.proc is not None and d.proc.returncode == 0, d.stderr()
    yield trace


def trace_json(*args: str) -> dict[str, Any]:
    run = motorctl("trace", "--json", *args)
    assert run.returncode == 0, run.stderr
    doc: dict[str, Any] = json.loads(run.stdout)
    return doc


@pytest.fixture(scope="module")
def plugin(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The dissector as the package builds it from the command table (client/dissector.py)."""
    path = tmp_path_factory.mktemp("wireshark") / "motorctl.lua"
    assert dissector.main(["--output", str(path)]) == 0
    return path


def tshark(plugin: Path, path: Path, *fields: str) -> list[list[str]]:
    assert TSHARK is not None
    args = [TSHARK, "-X", f"lua_script:{plugin}", "-r", str(path), "-T", "fields"]
    for f in fields:
        args += ["-e", f]
    run = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "Lua: Error" not in run.stderr and "lua" not in run.stderr.lower(), run.stderr
    return [line.split("\t") for line in run.stdout.splitlines()]


def _values(cell: str) -> list[str]:
    return [v for v in cell.split(",") if v != ""]


def per_packet_from_json(doc: dict[str, Any], interface: int | None = None) -> dict[int, Any]:
    """What each packet carries, from motorctl trace --json: kinds, commands, motors,
    positions, frame numbers, error names and frame errors, each in row order."""
    out: dict[int, Any] = {}
    for row in doc["rows"]:
        if interface is not None and row["interface"] != interface:
            continue
        p = out.setdefault(row["packet"], [[] for _ in FIELDS[1:]])
        kind = row["kind"]
        values = [kind, row["command"], row["motor"], row["position"], row["frame"]]
        values += [row["error_name"], row["error"] if kind == "bad_frame" else None]
        for column, value in zip(p, values, strict=True):
            if value is not None:
                column.append(str(value))
    return out


def per_packet_from_tshark(rows: list[list[str]]) -> dict[int, Any]:
    out: dict[int, Any] = {}
    for cells in rows:
        values = [_values(c) for c in cells[1:]]
        if any(values):
            out[int(cells[0])] = values
    return out


# --- the dissector ----------------------------------------------------------------------------


def test_the_dissector_knows_the_checksums_protocol_crc_knows() -> None:
    """client/wireshark/motorctl.lua.in carries its own copy of the CRC-8 catalogue."""
    lua = TEMPLATE.read_text()
    found = {
        m["name"]: (
            int(m["poly"], 16),
            int(m["init"], 16),
            m["refin"],
            m["refout"],
            int(m["xor"], 16),
        )
        for m in re.finditer(
            r'name = "(?P<name>[^"]+)", poly = 0x(?P<poly>\w+), init = 0x(?P<init>\w+), '
            r"refin = (?P<refin>\w+), refout = (?P<refout>\w+), xorout = 0x(?P<xor>\w+)",
            lua,
        )
    }
    assert found == {
        name: (c.poly, c.init, str(c.refin).lower(), str(c.refout).lower(), c.xorout)
        for name, c in CATALOGUE.items()
    }
    names = re.findall(r'name = "([^"]+)"', lua)
    smbus = re.search(r"local SMBUS = (\d+)", lua)
    assert smbus is not None and names.index("CRC-8/SMBUS") + 1 == int(smbus[1])  # "crc8"


def test_the_debian_package_installs_the_dissector_where_its_scripts_link_it() -> None:
    """debian/rules builds it from the command table into /usr/share/motorctl/wireshark,
    postinst links it into the Lua plugin folder of the machine's architecture, prerm removes
    that link (make test-deb checks both on a fresh Debian root; pyproject.toml ships the
    template in the wheel, which ``python3 -m motorctl.client.dissector`` fills)."""
    debian = REPO / "debian"
    target = "/usr/share/motorctl/wireshark/motorctl.lua"
    rules = " ".join((debian / "rules").read_text().replace("\\\n", " ").split())
    assert f"python3 -m motorctl.client.dissector --output debian/motorctl{target}" in rules
    postinst = (debian / "motorctl.postinst").read_text()
    assert f"motorctl_lua={target}" in postinst and 'get_config_var("MULTIARCH")' in postinst
    assert '"/usr/lib/$triplet/wireshark/plugins/motorctl.lua"' in postinst
    prerm = (debian / "motorctl.prerm").read_text()
    assert "/usr/lib/*/wireshark/plugins/motorctl.lua" in prerm and target in prerm
    assert '"motorctl.client" = ["wireshark/*.lua.in"]' in (REPO / "pyproject.toml").read_text()


@needs_tshark
def test_tshark_shows_what_motorctl_trace_json_shows_for_every_frame(
    recorded: Path, plugin: Path
) -> None:
    doc = trace_json(str(recorded))
    assert doc["summary"]["frames"] > 20 and doc["summary"]["gap_discards"] == 1
    expected = per_packet_from_json(doc)
    got = per_packet_from_tshark(tshark(plugin, recorded, *FIELDS))
    assert got == expected
    commands = [c for cells in got.values() for c in cells[1]]
    assert {"MoveTo", "WaitMoved", "GetAbsPos", "SetPin", "DcMove", "StopMove"} <= set(commands)


@needs_tshark
def test_tshark_checks_checksums_pairs_answers_and_names_errors(
    recorded: Path, plugin: Path
) -> None:
    rows = tshark(
        plugin,
        recorded,
        "frame.number",
        "motorctl.kind",
        "motorctl.checksum.status",
        "motorctl.request_in",
        "motorctl.answer",
        "motorctl.error_code",
        "motorctl.rtt",
        "motorctl.direction",
    )
    doc = trace_json(str(recorded))
    answers = {r["packet"]: r for r in doc["rows"] if r["kind"] == "answer"}
    commands = {
        r["frame"]: r["packet"] for r in doc["rows"] if r["kind"] in ("command", "bad_frame")
    }
    bad = [r["packet"] for r in doc["rows"] if r["kind"] == "bad_frame"]
    for number, kind, status, request, answer, code, rtt, _ in rows:
        n = int(number)
        if n in bad:
            assert "bad_frame" in kind and "0" in _values(status)  # the bad checksum, named
        if kind == "answer":
            row = answers[n]
            assert status == "1" and int(request) == commands.get(row["frame"], -1)
            assert answer == row["text"].split(" ", 1)[1]  # "#4 pos=400" -> "pos=400"
            assert (int(code, 16) if code else None) == row["error_code"]
            assert abs(float(rtt) * 1e6 - row["rtt_us"]) < 1
    dc = [r for r in rows if r[7] in ("forward", "reverse")]
    assert [r[7] for r in dc] == ["forward"]  # DcMove: forward, as the CLI says it


# --- merged files -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def merged(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The tap between a host and motorctld (with its own trace), then mergecap of the two."""
    if MERGECAP is None:
        pytest.skip(str(needs_mergecap.kwargs["reason"]))
    work = tmp_path_factory.mktemp("merged")
    device = DaemonProcess(
        subdir(work, "old"), CONFIG, extra=["--trace", str(work / "device.pcapng")]
    ).start()
    host, host_port = pty_pair()
    tap = start_tap(host_port, str(device.pty), work / "tap.pcapng")
    try:
        # nothing whose answer depends on timing: the replay below is exact
        for c in (IsReady(0), SetPin(3, True), MoveTo(9, True, 1, 0, 0, 0), GetAbsPos(0)):
            os.write(host, encode_command(c, OPTS))
            read_exactly(host, 5)
    finally:
        stop_tap(tap)
        os.close(host)
        device.close()
    out = work / "merged.pcapng"
    run = subprocess.run(
        [MERGECAP, "-w", str(out), str(work / "tap.pcapng"), str(work / "device.pcapng")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    yield out


def test_a_merged_file_is_read_link_by_link(merged: Path) -> None:
    run = motorctl("trace", "--json", str(merged))
    assert run.returncode == 0, run.stderr
    assert re.search(
        r"holds interfaces 0: host \S+ <-> device \S+ \(tap, \d+ runs\), 1: ", run.stderr
    )
    assert re.search(r"\(daemon, \d+ runs\): each decoded as its own link", run.stderr)
    doc = json.loads(run.stdout)
    assert [(i["interface"], i["role"]) for i in doc["interfaces"]] == [(0, "tap"), (1, "daemon")]
    for link in doc["links"]:  # each link by itself: every frame once, every answer paired
        s = link["summary"]
        assert (s["frames"], s["answers"], s["extra_answers"], s["unanswered"]) == (4, 4, 0, [])
    texts = {i: [r["text"] for r in doc["rows"] if r["interface"] == i] for i in (0, 1)}
    assert texts[0] == texts[1] and "#3 E2 Invalid Address" in texts[0]
    one = motorctl("trace", "--json", "--interface", "1", str(merged))
    assert json.loads(one.stdout)["info"]["role"] == "daemon"
    assert {r["interface"] for r in json.loads(one.stdout)["rows"]} == {1}


def test_the_replay_of_a_merged_file_asks_which_link_and_plays_the_one_named(
    merged: Path, tmp_path: Path
) -> None:
    refused = motorctl("replay", str(merged), "--port", "/nonexistent")
    assert refused.returncode == 2
    assert "2 motorctl links" in refused.stderr and "pass --interface N" in refused.stderr
    d = DaemonProcess(tmp_path, CONFIG).start()
    try:
        run = motorctl("replay", str(merged), "--interface", "1", "--port", str(d.pty))
    finally:
        d.close()
    assert run.returncode == 0, run.stdout + run.stderr
    assert "replay of 4 frames" in run.stdout


@needs_tshark
def test_tshark_decodes_each_interface_of_a_merged_file_on_its_own(
    merged: Path, plugin: Path
) -> None:
    doc = trace_json(str(merged))
    got = per_packet_from_tshark(tshark(plugin, merged, *FIELDS))
    assert got == per_packet_from_json(doc)


# --- rotated parts ----------------------------------------------------------------------------


def test_a_rotation_that_lost_parts_is_named_by_trace_and_replay(tmp_path: Path) -> None:
    """A daemon whose trace rotates every 10 KiB, 3 files kept: the oldest parts go."""
    config = CONFIG + "\n[trace]\nmax_file_mb = 0.01\nfiles = 3\n"
    trace = tmp_path / "link.pcapng"
    d = DaemonProcess(tmp_path, config, extra=["--trace", str(trace)]).start()
    try:
        with d.client() as c:
            for _ in range(450):
                assert c.is_ready(0)
        assert d.status()["trace"]["session"]
    finally:
        d.close()
    newest = parse(trace.read_bytes()).info
    assert newest is not None and newest.part > 3  # parts 1.. have rotated away
    parts = [trace.with_name(f"link.pcapng.{i}") for i in (2, 1)] + [trace]
    run = motorctl("trace", "--json", *map(str, parts))
    assert run.returncode == 0, run.stderr
    assert f"the start of session {newest.session}" in run.stderr
    rows = json.loads(run.stdout)["rows"]
    assert {r["file"] for r in rows} == set(map(str, parts))
    replay = motorctl("replay", *map(str, parts), "--port", "/nonexistent")
    assert "start of session" in replay.stderr  # the same warning, then the port
    hole = motorctl("trace", str(parts[0]), str(trace))  # the middle part left out
    assert f"lacks part {newest.part - 1}" in hole.stderr


# --- pcap -------------------------------------------------------------------------------------


def to_pcap(path: Path, out: Path) -> None:
    """editcap -F pcap when there is one, else the same by hand."""
    editcap = shutil.which("editcap")
    if editcap is not None:
        subprocess.run([editcap, "-F", "pcap", str(path), str(out)], check=True, timeout=60)
        return
    data = struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 0, LINKTYPE_USER0)
    for r in parse(path.read_bytes()).records:
        data += struct.pack("<IIII", r.ts_ns // 10**9, r.ts_ns % 10**9, len(r.data), len(r.data))
        data += r.data
    out.write_bytes(data)


def test_a_pcap_file_is_named_and_read_where_its_bytes_tell_the_direction(
    recorded: Path, tmp_path: Path
) -> None:
    out = tmp_path / "session.pcap"
    to_pcap(recorded, out)
    run = motorctl("trace", "--json", str(out))
    assert run.returncode == 0, run.stderr
    assert "a pcap file (not pcapng): pcap keeps no directions" in run.stderr
    assert "could not be (the first at offset" in run.stderr  # the partial frames
    doc = json.loads(run.stdout)
    own = trace_json(str(recorded))

    # every command the pcap file still shows, the pcapng file shows in the same place
    def commands(rows: list[dict[str, Any]]) -> list[tuple[int, str]]:  # "#4 X(...)" -> "X(...)"
        return [(r["packet"], r["text"].split(" ", 1)[1]) for r in rows if r["kind"] == "command"]

    pcap_cmds, own_cmds = commands(doc["rows"]), set(commands(own["rows"]))
    assert len(pcap_cmds) > 20 and set(pcap_cmds) <= own_cmds


# --- damaged files ----------------------------------------------------------------------------


PARSER = cli.build_parser()


def cli_run(*args: str) -> tuple[int, str, str]:
    """motorctl trace or replay in this process (hundreds of runs: no interpreter start,
    one parser)."""
    parsed = PARSER.parse_args(list(args))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = (trace.run if parsed.command == "trace" else replay.run)(parsed)
    return status, out.getvalue(), err.getvalue()


def named(message: str) -> bool:
    """A problem or an error of the reader says where: an offset (or it is about a
    session's parts, or the file's format or emptiness)."""
    return any(w in message for w in ("offset", "session", "a pcap file", "is empty"))


def check_read(path: Path, data: bytes | None = None) -> bool:
    """The reader on a damaged file (``data``: its bytes, not written out): read (True) or
    refused (False), never anything else, every problem it names and its refusal naming
    where."""
    try:
        problems = links_of([(path, read(path, data))]).problems
    except TraceFileError as exc:
        assert named(str(exc)), exc
        return False
    for p in problems:
        assert named(p), p
    return True


def check_tools(path: Path) -> None:
    """``motorctl trace`` and ``motorctl replay`` on a damaged file: no traceback and the
    same verdict: replay goes on to the port exactly when trace reads the file (or says there
    is nothing to replay), or both print the same error; both warn of the same problems."""
    status, _, err = cli_run("trace", str(path))
    assert status in (0, 2), err
    r_status, r_out, r_err = cli_run("replay", str(path), "--port", "/nonexistent/port")
    assert r_status == 2 and "no difference" not in r_out
    assert status == (0 if check_read(path) else 2)
    if status == 2:
        assert r_err == err, (err, r_err)  # the same message, word for word
        return
    assert "cannot open /nonexistent/port" in r_err or "nothing to replay" in r_err, r_err
    for p in load([path]).problems:
        assert f"warning: {p}" in err and f"warning: {p}" in r_err


def _block_starts(data: bytes) -> set[int]:
    return {r.offset for r in parse(data).records} | {0, len(data)}


def test_every_truncation_point_of_a_real_recording(recorded: Path, tmp_path: Path) -> None:
    data = recorded.read_bytes()
    edges = _block_starts(data)
    cut = tmp_path / "cut.pcapng"
    for n in range(len(data)):
        check_read(cut, data[:n])
        if n % 32 == 0 or n in edges:  # the tools too, on a sample
            cut.write_bytes(data[:n])
            check_tools(cut)


def test_random_byte_flips_in_a_real_recording(recorded: Path, tmp_path: Path) -> None:
    data = recorded.read_bytes()
    rng = random.Random(2627)
    flipped = tmp_path / "flipped.pcapng"
    for i in range(500):
        damaged = bytearray(data)
        for _ in range(rng.choice((1, 1, 2, 3))):
            damaged[rng.randrange(len(damaged))] ^= 1 << rng.randrange(8)
        check_read(flipped, bytes(damaged))
        if i % 5 == 0:
            flipped.write_bytes(bytes(damaged))
            check_tools(flipped)


def test_pcap_and_foreign_files_cut_anywhere(recorded: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "session.pcap"
    to_pcap(recorded, pcap)
    data = pcap.read_bytes()
    cut = tmp_path / "cut.pcap"
    for n in range(len(data)):
        check_read(cut, data[:n])
        if n % 64 == 0:
            cut.write_bytes(data[:n])
            check_tools(cut)
    ether = bytearray(data)
    struct.pack_into("<I", ether, 20, 1)
    cut.write_bytes(bytes(ether))
    status, _, err = cli_run("trace", str(cut))
    assert status == 2 and "link type 1 (Ethernet)" in err
    cut.write_bytes(b"GIF89a not a capture")
    status, _, err = cli_run("trace", str(cut))
    assert status == 2 and "not a pcapng or pcap file" in err


def test_a_recording_cut_to_50_bytes_replays_nothing_and_fails(
    recorded: Path, tmp_path: Path
) -> None:
    cut = tmp_path / "cut.pcapng"
    cut.write_bytes(recorded.read_bytes()[:50])
    d = DaemonProcess(tmp_path, CONFIG).start()
    try:
        run = motorctl("replay", str(cut), "--port", str(d.pty))
    finally:
        d.close()
    assert run.returncode == 2, run.stdout + run.stderr
    assert "no difference" not in run.stdout and "Traceback" not in run.stderr
    assert "ends inside its first block at offset 0" in run.stderr
    empty = tmp_path / "empty.pcapng"  # a header and nothing else: read, but nothing to play
    records = parse(recorded.read_bytes()).records
    empty.write_bytes(recorded.read_bytes()[: records[0].offset])
    status, _, err = cli_run("replay", str(empty), "--port", "/nonexistent")
    assert status == 2 and "nothing to replay" in err
    assert cli_run("trace", str(empty))[0] == 0  # an empty recording is a recording


def test_output_into_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    """motorctl trace FILE | head: no BrokenPipeError traceback."""
    from motorctl.protocol.capture.format import CaptureInfo, Record
    from motorctl.protocol.capture.writer import encode
    from motorctl.protocol.codec import Response, encode_response

    recs = []
    for i in range(5000):
        recs.append(Record(i * 10**6, Direction.TO_DEVICE, encode_command(IsReady(0), OPTS)))
        recs.append(
            Record(i * 10**6 + 10**5, Direction.TO_HOST, encode_response(Response.ok(), OPTS))
        )
    big = tmp_path / "big.pcapng"
    big.write_bytes(encode(CaptureInfo(), recs))
    run = subprocess.run(
        f"{sys.executable} -m motorctl.client.cli trace {big} | head -3",
        shell=True,
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert len(run.stdout.splitlines()) == 3
    assert run.stderr == "", run.stderr
