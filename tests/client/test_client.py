"""Client and CLI against a scripted peer on a real PTY (not the daemon)."""

from __future__ import annotations

import os
import queue
import select
import threading
import tty
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from motorctl.client import cli
from motorctl.client.client import Client, DeviceError, LinkError
from motorctl.protocol.codec import (
    CodecOptions,
    ErrorCode,
    FrameError,
    IsReady,
    Response,
    decode_command,
    encode_response,
)
from motorctl.protocol.crc import crc8_by_name
from tests.support.frames import raw_frame, ref_crc8

# -- reference checksum and frames --------------------------------------------------------


def resp(hex_text: str) -> bytes:
    """Response frame: R0..R3 as given, reference CRC over R1..R3."""
    head = bytes.fromhex(hex_text)
    return head + bytes([ref_crc8(head[1:])])


def test_reference_checksum_matches_protocol() -> None:
    assert ref_crc8(b"123456789") == 0xF4
    assert raw_frame("03 00") == bytes.fromhex("03 00 00 00 00 00 00 00 00 8B")


# -- the scripted peer --------------------------------------------------------------------

SILENT = object()
"""Reply item: read the frame, answer nothing."""


@dataclass(frozen=True)
class Delayed:
    """Reply item: answer ``reply`` after ``seconds``."""

    seconds: float
    reply: Response | bytes


class Peer:
    """Reads 10-byte frames from the PTY master and answers with scripted replies.

    A frame the codec refuses (checksum, padding, unknown code) is answered E1 without using
    a scripted reply; a frame with no reply scripted is recorded in ``errors``.
    """

    def __init__(self, master: int, port: str, opts: CodecOptions) -> None:
        self.master = master
        self.port = port
        self.opts = opts
        self.frames: queue.Queue[bytes] = queue.Queue()
        self.errors: list[str] = []
        self._replies: queue.Queue[object] = queue.Queue()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="pty-peer", daemon=True)
        self._thread.start()

    def answer(self, *replies: object) -> None:
        """Script the replies to the next frames, in order."""
        for reply in replies:
            self._replies.put(reply)

    def next_frame(self) -> bytes:
        """The oldest frame received and not yet taken."""
        return self.frames.get(timeout=2.0)

    def stop(self) -> None:
        self._stop.set()
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=2.0)
        assert not self._thread.is_alive(), "peer thread did not stop"
        os.close(self._wake_r)
        os.close(self._wake_w)

    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master, self._wake_r], [], [])
            if self._wake_r in ready:
                return
            buf += os.read(self.master, 4096)
            while len(buf) >= 10:
                data, buf = buf[:10], buf[10:]
                self.frames.put(data)
                self._reply(data)

    def _reply(self, data: bytes) -> None:
        try:
            decode_command(data, self.opts)
        except FrameError:
            self._write(Response.error(ErrorCode.INVALID_COMMAND))
            return
        try:
            reply = self._replies.get_nowait()
        except queue.Empty:
            self.errors.append(f"unexpected frame {data.hex(' ')}")
            return
        if isinstance(reply, Delayed):
            if self._stop.wait(reply.seconds):
                return
            reply = reply.reply
        if reply is not SILENT:
            assert isinstance(reply, Response | bytes)
            self._write(reply)

    def _write(self, reply: Response | bytes) -> None:
        data = reply if isinstance(reply, bytes) else encode_response(reply, self.opts)
        os.write(self.master, data)


PeerFactory = Callable[..., Peer]


@pytest.fixture
def make_peer(tmp_path: Path) -> Iterator[PeerFactory]:
    """Start peers on fresh PTYs (reached through a symlink); stop and check them after."""
    peers: list[tuple[Peer, int, int]] = []

    def start(opts: CodecOptions | None = None) -> Peer:
        master, slave = os.openpty()
        tty.setraw(slave)
        link = tmp_path / f"ttyMOTOR{len(peers)}"
        link.symlink_to(os.ttyname(slave))
        peer = Peer(master, str(link), opts if opts is not None else CodecOptions())
        peers.append((peer, master, slave))
        return peer

    yield start
    for peer, master, slave in peers:
        peer.stop()
        os.close(master)
        os.close(slave)
    for peer, _, _ in peers:
        assert peer.errors == []


@pytest.fixture
def peer(make_peer: PeerFactory) -> Peer:
    return make_peer()


@pytest.fixture
def client(peer: Peer) -> Iterator[Client]:
    with Client(peer.port, timeout=2.0) as c:
        yield c


# -- typed methods ------------------------------------------------------------------------

OK = Response.ok()

TYPED_CASES: list[tuple[str, Callable[[Client], Any], str, Response, Any]] = [
    ("init", lambda c: c.init_move(1, False, 10, 20, 30), "00 01 00 0a 14 1e", OK, None),
    ("init-defaults", lambda c: c.init_move(0, True), "00 00 01", OK, None),
    ("moveto", lambda c: c.move_to(0, 1200, 250), "01 00 01 00 04 b0 fa", OK, None),
    (
        "moveto-negative",
        lambda c: c.move_to(2, -500, 1, 2, 3, direction=False),
        "01 02 00 ff fe 0c 01 02 03",
        OK,
        None,
    ),
    ("moveto-min", lambda c: c.move_to(0, -8388608), "01 00 01 80 00 00", OK, None),
    ("moveto-max", lambda c: c.move_to(0, 8388607), "01 00 01 7f ff ff", OK, None),
    ("wait", lambda c: c.wait_moved(1, 1500), "02 01 05 dc", OK, None),
    ("ready-true", lambda c: c.is_ready(0), "03 00", Response(True, b"\x01\x00\x00"), True),
    ("ready-false", lambda c: c.is_ready(3), "03 03", Response(True, b"\x00\x00\x00"), False),
    ("ready-ff", lambda c: c.is_ready(0), "03 00", Response(True, b"\xff\x00\x00"), True),
    ("move", lambda c: c.move(3, True, 5, 6, 7), "04 03 01 05 06 07", OK, None),
    ("stop-soft", lambda c: c.stop(0), "05 00 00", OK, None),
    ("stop-hard", lambda c: c.stop(1, hard=True), "05 01 01", OK, None),
    ("pos", lambda c: c.position(0), "06 00", Response(True, b"\xff\xfb\x50"), -1200),
    ("pos-max", lambda c: c.position(2), "06 02", Response(True, b"\x7f\xff\xff"), 8388607),
    ("pos-min", lambda c: c.position(2), "06 02", Response(True, b"\x80\x00\x00"), -8388608),
    ("set-high", lambda c: c.set_pin(4, True), "07 04 01", OK, None),
    ("set-low", lambda c: c.set_pin(4, False), "07 04 00", OK, None),
    ("get-high", lambda c: c.get_pin(4), "08 04", Response(True, b"\x01\x00\x00"), True),
    ("get-low", lambda c: c.get_pin(9), "08 09", Response(True, b"\x00\x00\x00"), False),
    ("config-out", lambda c: c.config_pin(5, True), "09 05 01", OK, None),
    ("config-in", lambda c: c.config_pin(5, False), "09 05 00", OK, None),
    ("save-home", lambda c: c.save_home(1), "0a 01", OK, None),
    ("go-home", lambda c: c.go_home(1), "0b 01", OK, None),
    ("save-wp", lambda c: c.save_waypoint(0), "0c 00", Response(True, b"\x03\x00\x00"), 3),
    ("go-wp", lambda c: c.move_to_waypoint(1, 3, 9, 8, 7), "0d 01 03 09 08 07", OK, None),
    ("dc-fwd-brake", lambda c: c.dc_move(True, 300, False), "0e 01 01 2c 00", OK, None),
    ("dc-rev-hiz", lambda c: c.dc_move(False, 65535, True), "0e 00 ff ff 01", OK, None),
]


@pytest.mark.parametrize(
    ("call", "body", "reply", "expected"),
    [case[1:] for case in TYPED_CASES],
    ids=[case[0] for case in TYPED_CASES],
)
def test_typed_method_frame_and_result(
    peer: Peer,
    client: Client,
    call: Callable[[Client], Any],
    body: str,
    reply: Response,
    expected: Any,
) -> None:
    peer.answer(reply)
    assert call(client) == expected
    sent = peer.next_frame()
    assert sent == raw_frame(body)
    assert client.last_request == sent
    assert client.last_response == encode_response(reply, CodecOptions())


def test_out_of_range_field_is_refused_before_sending(peer: Peer, client: Client) -> None:
    with pytest.raises(ValueError, match="position"):
        client.move_to(0, 8388608)
    with pytest.raises(ValueError, match="speed"):
        client.move(0, True, speed=256)
    assert peer.frames.empty()


def test_wait_moved_reads_longer_than_client_timeout(peer: Peer) -> None:
    # The device holds the answer longer than the client's own timeout but within
    # timeout_ms: wait_moved must still get it.
    with Client(peer.port, timeout=0.1) as c:
        peer.answer(Delayed(0.4, OK))
        c.wait_moved(0, 1000)
    assert peer.next_frame() == raw_frame("02 00 03 e8")


# -- device errors ------------------------------------------------------------------------


@pytest.mark.parametrize("code", list(ErrorCode), ids=lambda c: c.short)
def test_device_error_carries_code_and_command(peer: Peer, client: Client, code: ErrorCode) -> None:
    peer.answer(Response.error(code))
    with pytest.raises(DeviceError) as info:
        client.is_ready(2)
    assert info.value.code is code
    assert info.value.command == IsReady(2)
    assert str(info.value) == f"E{code - 0xE0} {code.label.lower()}"


def test_device_error_names(peer: Peer, client: Client) -> None:
    peer.answer(
        Response.error(ErrorCode.MOTOR_NOT_READY),
        Response.error(ErrorCode.INVALID_WAYPOINT),
        Response(False, b"\x42\x00\x00"),
    )
    with pytest.raises(DeviceError, match=r"^E3 motor not ready$"):
        client.save_home(0)
    with pytest.raises(DeviceError, match=r"^E6 invalid way point$"):
        client.move_to_waypoint(0, 7)
    with pytest.raises(DeviceError, match=r"^unknown error code 0x42$") as info:
        client.go_home(0)
    assert info.value.code == 0x42


def test_transact_returns_error_response(peer: Peer, client: Client) -> None:
    peer.answer(Response.error(ErrorCode.MOTOR_ERROR))
    got = client.transact(IsReady(0))
    assert not got.ack
    assert got.error_code is ErrorCode.MOTOR_ERROR


# -- link errors --------------------------------------------------------------------------


def test_silence_is_a_link_error(peer: Peer) -> None:
    with Client(peer.port, timeout=0.15) as c:
        peer.answer(SILENT)
        with pytest.raises(LinkError) as info:
            c.is_ready(0)
    text = str(info.value)
    assert "no response" in text
    assert raw_frame("03 00").hex(" ") in text
    assert "IsReady(motor=0)" in text


def test_short_response_is_a_link_error(peer: Peer) -> None:
    with Client(peer.port, timeout=0.15) as c:
        peer.answer(b"\x01\x00")
        with pytest.raises(LinkError, match=r"short response.*got 01 00 \(2 of 5 bytes\)"):
            c.position(0)
        assert c.last_response == b"\x01\x00"


def test_corrupted_response_checksum_is_a_link_error(peer: Peer, client: Client) -> None:
    bad = bytearray(resp("01 01 00 00"))
    bad[4] ^= 0x5A
    peer.answer(bytes(bad))
    with pytest.raises(LinkError, match="bad response") as info:
        client.is_ready(0)
    assert bytes(bad).hex(" ") in str(info.value)
    assert client.last_response == bytes(bad)


def test_crc_covers_ack_mismatch_is_a_link_error(make_peer: PeerFactory) -> None:
    covering = CodecOptions(crc_covers_ack=True)
    p = make_peer(covering)
    p.answer(Response.boolean(True), Response.boolean(True))
    with Client(p.port, timeout=2.0, options=covering) as c:
        assert c.is_ready(0) is True
    with Client(p.port, timeout=2.0) as c, pytest.raises(LinkError, match="checksum"):
        c.is_ready(0)


# -- raw access: pipelined, split and broken frames --------------------------------------


def test_pipelined_frames_answered_in_order(peer: Peer, client: Client) -> None:
    peer.answer(Response.position(-7), Response.boolean(True))
    client.send_frame(raw_frame("06 00"))
    client.send_frame(raw_frame("03 00"))
    assert client.read_response().as_position == -7
    assert client.read_response().as_bool is True
    assert [peer.next_frame(), peer.next_frame()] == [raw_frame("06 00"), raw_frame("03 00")]


def test_split_frame_and_read_raw(peer: Peer, client: Client) -> None:
    peer.answer(Response.boolean(False))
    whole = raw_frame("03 01")
    client.send_bytes(whole[:3])
    client.send_bytes(whole[3:])
    assert client.last_request == whole[3:]
    assert client.read_raw(5) == resp("01 00 00 00")
    assert peer.next_frame() == whole


def test_broken_frame_gets_the_peers_e1(peer: Peer, client: Client) -> None:
    broken = bytearray(raw_frame("03 00"))
    broken[9] ^= 0xFF
    client.send_frame(bytes(broken))
    got = client.read_response()
    assert got.error_code is ErrorCode.INVALID_COMMAND


def test_send_frame_wants_ten_bytes(client: Client) -> None:
    with pytest.raises(ValueError, match="10 bytes"):
        client.send_frame(b"\x03\x00")


def test_checksum_none(make_peer: PeerFactory) -> None:
    none = CodecOptions(crc=None)
    p = make_peer(none)
    # With checksum "none" the checksum byte is sent as 0x00 and ignored on input.
    p.answer(b"\x01\x01\x00\x00\x77")
    with Client(p.port, timeout=2.0, options=none) as c:
        assert c.is_ready(5) is True
    assert p.next_frame() == bytes.fromhex("03 05 00 00 00 00 00 00 00 00")


def test_close_is_idempotent(peer: Peer) -> None:
    c = Client(peer.port, timeout=0.5)
    c.close()
    c.close()


# -- CLI ----------------------------------------------------------------------------------

CLI_CASES: list[tuple[list[str], str, Response, str]] = [
    (["init", "0", "up"], "00 00 01", OK, "ok"),
    (
        ["init", "1", "down", "--speed", "3", "--acc", "4", "--dec", "5"],
        "00 01 00 03 04 05",
        OK,
        "ok",
    ),
    (["moveto", "0", "1200", "--speed", "250"], "01 00 01 00 04 b0 fa", OK, "ok"),
    (
        ["moveto", "1", "0x10", "--dir", "down", "--dec", "9"],
        "01 01 00 00 00 10 00 00 09",
        OK,
        "ok",
    ),
    (["moveto", "0", "-500"], "01 00 01 ff fe 0c", OK, "ok"),
    (["moveto", "0", "-500", "--speed", "3"], "01 00 01 ff fe 0c 03", OK, "ok"),
    (["moveto", "0", "-0x1f4"], "01 00 01 ff fe 0c", OK, "ok"),
    (["moveto", "0", "-8388608"], "01 00 01 80 00 00", OK, "ok"),
    (["wait", "2"], "02 02 ea 60", OK, "ok"),
    (["wait", "2", "250"], "02 02 00 fa", OK, "ok"),
    (["ready", "0"], "03 00", Response.boolean(True), "motor 0 ready"),
    (["ready", "1"], "03 01", Response.boolean(False), "motor 1 busy"),
    (["move", "2", "up", "--speed", "1"], "04 02 01 01", OK, "ok"),
    (["stop", "0"], "05 00 00", OK, "ok"),
    (["stop", "0", "--hard"], "05 00 01", OK, "ok"),
    (["pos", "0"], "06 00", Response(True, b"\x00\x04\xb0"), "motor 0 at 1200"),
    (["pos", "1"], "06 01", Response(True, b"\xff\xfe\x0c"), "motor 1 at -500"),
    (["pin", "set", "4", "high"], "07 04 01", OK, "ok"),
    (["pin", "set", "4", "low"], "07 04 00", OK, "ok"),
    (["pin", "get", "4"], "08 04", Response.boolean(True), "pin 4 high"),
    (["pin", "get", "6"], "08 06", Response.boolean(False), "pin 6 low"),
    (["pin", "config", "5", "out"], "09 05 01", OK, "ok"),
    (["pin", "config", "5", "output"], "09 05 01", OK, "ok"),
    (["pin", "config", "5", "in"], "09 05 00", OK, "ok"),
    (["pin", "config", "5", "input"], "09 05 00", OK, "ok"),
    (["home", "save", "1"], "0a 01", OK, "ok"),
    (["home", "go", "1"], "0b 01", OK, "ok"),
    (
        ["waypoint", "save", "0"],
        "0c 00",
        Response(True, b"\x03\x00\x00"),
        "waypoint 3 saved on motor 0",
    ),
    (["waypoint", "go", "0", "3", "--speed", "2"], "0d 00 03 02", OK, "ok"),
    (["dc", "forward", "300"], "0e 01 01 2c 00", OK, "ok"),
    (["dc", "reverse", "300", "--hiz"], "0e 00 01 2c 01", OK, "ok"),
    (["dc", "forward", "0", "--brake"], "0e 01 00 00 00", OK, "ok"),
    (
        ["send", "03", "00", "00", "00", "00", "00", "00", "00", "00"],
        "03 00",
        Response(True, b"\x01\x02\x03"),
        "ok, payload 01 02 03",
    ),
    (["send", "030200000000000000"], "03 02", OK, "ok, payload 00 00 00"),
]


@pytest.mark.parametrize(
    ("args", "body", "reply", "out"), CLI_CASES, ids=[" ".join(c[0]) for c in CLI_CASES]
)
def test_cli_success(
    peer: Peer,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    body: str,
    reply: Response,
    out: str,
) -> None:
    peer.answer(reply)
    assert cli.main(["-p", peer.port, *args]) == 0
    assert peer.next_frame() == raw_frame(body)
    captured = capsys.readouterr()
    assert captured.out == out + "\n"
    assert captured.err == ""


def test_cli_device_error(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    peer.answer(Response.error(ErrorCode.MOTOR_NOT_READY))
    assert cli.main(["-p", peer.port, "home", "save", "0"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    # no daemon's status socket here: the code's meaning for the command (client/reasons.py)
    assert captured.err == (
        "error: E3 motor not ready: motor 0 is moving or has commands queued; it must be at rest\n"
    )


def test_cli_raw(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    peer.answer(Response(True, b"\x00\x04\xb0"))
    assert cli.main(["-p", peer.port, "--raw", "pos", "0"]) == 0
    sent = raw_frame("06 00").hex(" ")
    got = resp("01 00 04 b0").hex(" ")
    assert capsys.readouterr().out == f"-> {sent}\n<- {got}\nmotor 0 at 1200\n"


def test_cli_raw_on_device_error(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    peer.answer(Response.error(ErrorCode.INVALID_ADDRESS))
    assert cli.main(["--raw", "-p", peer.port, "ready", "9"]) == 1
    captured = capsys.readouterr()
    assert captured.out == f"-> {raw_frame('03 09').hex(' ')}\n<- {resp('00 e2 00 00').hex(' ')}\n"
    assert captured.err == "error: E2 invalid address: no motor 9\n"


def test_cli_send_ten_bytes_as_is(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    # A wrong checksum is sent unchanged; the peer answers E1 as the device would.
    assert cli.main(["-p", peer.port, "send", "03 00 00 00 00 00 00 00 00 00"]) == 1
    assert peer.next_frame() == bytes.fromhex("03 00 00 00 00 00 00 00 00 00")
    assert capsys.readouterr().err == (
        "error: E1 invalid command: the frame was refused: a wrong checksum, an unknown "
        "command or non-zero padding\n"
    )


def test_cli_send_ten_bytes_good_checksum(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    peer.answer(Response.boolean(True))
    assert cli.main(["-p", peer.port, "send", *raw_frame("03 07").hex(" ").split()]) == 0
    assert peer.next_frame() == raw_frame("03 07")
    assert capsys.readouterr().out == "ok, payload 01 00 00\n"


def test_cli_link_error(peer: Peer, capsys: pytest.CaptureFixture[str]) -> None:
    peer.answer(SILENT)
    assert cli.main(["-p", peer.port, "--timeout", "0.15", "ready", "0"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("error: IsReady(motor=0): no response to 03 00")


def test_cli_checksum_none(make_peer: PeerFactory, capsys: pytest.CaptureFixture[str]) -> None:
    p = make_peer(CodecOptions(crc=None))
    p.answer(Response.boolean(True), Response.ok())
    assert cli.main(["-p", p.port, "--checksum", "none", "ready", "0"]) == 0
    assert p.next_frame() == bytes.fromhex("03 00 00 00 00 00 00 00 00 00")
    # send with 9 bytes appends 0x00 in "none" mode.
    assert cli.main(["-p", p.port, "--checksum", "none", "send", "0b0100000000000000"]) == 0
    assert p.next_frame() == bytes.fromhex("0b 01 00 00 00 00 00 00 00 00")
    assert capsys.readouterr().out == "motor 0 ready\nok, payload 00 00 00\n"


def test_cli_catalogue_checksum_and_covers_ack(
    make_peer: PeerFactory, capsys: pytest.CaptureFixture[str]
) -> None:
    maxim = crc8_by_name("CRC-8/MAXIM-DOW")
    p = make_peer(CodecOptions(crc=maxim, crc_covers_ack=True))
    p.answer(Response.position(42))
    argv = ["-p", p.port, "--checksum", "maxim-dow", "--crc-covers-ack", "pos", "3"]
    assert cli.main(argv) == 0
    body = bytes.fromhex("06 03 00 00 00 00 00 00 00")
    assert p.next_frame() == body + bytes([maxim.compute(body)])
    assert capsys.readouterr().out == "motor 3 at 42\n"


def test_cli_port_from_environment(
    peer: Peer, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MOTORCTL_PORT", peer.port)
    peer.answer(Response.boolean(False))
    assert cli.main(["pin", "get", "2"]) == 0
    assert capsys.readouterr().out == "pin 2 low\n"


def test_cli_without_port_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("MOTORCTL_PORT", raising=False)
    with pytest.raises(SystemExit) as info:
        cli.main(["ready", "0"])
    assert info.value.code == 2
    assert "-p" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args",
    [
        ["moveto", "0", "8388608"],
        ["moveto", "0", "-8388609"],
        ["init", "0", "sideways"],
        ["ready", "256"],
        ["move", "0", "up", "--speed", "300"],
        ["wait", "0", "65536"],
        ["dc", "forward", "10", "--brake", "--hiz"],
        ["pin", "config", "1", "sideways"],
        ["send", "03", "00"],
        ["send", "zz"],
        ["--checksum", "crc-9000", "ready", "0"],
        ["--timeout", "0", "ready", "0"],
        ["--timeout", "inf", "ready", "0"],  # an OverflowError in pyserial's select, before
        ["--timeout", "1e300", "ready", "0"],
        ["bogus"],
    ],
    ids=lambda a: " ".join(a),
)
def test_cli_usage_errors(peer: Peer, capsys: pytest.CaptureFixture[str], args: list[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["-p", peer.port, *args])
    assert info.value.code == 2
    assert capsys.readouterr().err
    assert peer.frames.empty()


def test_cli_unopenable_port(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["-p", str(tmp_path / "nope"), "ready", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: cannot open")


def test_cli_help_states_raw_units(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    assert "raw protocol values" in capsys.readouterr().out
    with pytest.raises(SystemExit) as info:
        cli.main(["moveto", "--help"])
    assert "Numbers are the protocol's raw values (motorctl --help)." in " ".join(
        capsys.readouterr().out.split()
    )
