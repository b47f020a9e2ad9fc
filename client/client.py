"""Host-side client for the motorctl device protocol over a serial port.

One :class:`Client` talks to one port. :meth:`Client.transact` sends one command frame and
reads one response; :meth:`Client.call` sends any command of the command table
(motorctl.protocol.commands), raises :class:`DeviceError` on an error response and returns the
answer read for it (its value, its text); the typed methods (``is_ready``, ``position`` ...)
wrap it and return the value as a Python value. The low
level methods (``send_frame``, ``send_bytes``, ``read_response``, ``read_raw``) let tests
pipeline frames, send broken frames or split a frame.
"""

from __future__ import annotations

import time
from types import TracebackType

import serial

from motorctl.protocol.codec import (
    FRAME_LEN,
    RESPONSE_LEN,
    CodecOptions,
    Command,
    ConfigPin,
    DcMove,
    ErrorCode,
    GetAbsPos,
    GetPin,
    GoHome,
    InitMove,
    IsReady,
    Move,
    MoveTo,
    MoveToWayPoint,
    Reading,
    Response,
    ResponseError,
    SaveHome,
    SaveWayPoint,
    SetPin,
    StopMove,
    WaitMoved,
    decode_answer,
    decode_response,
    describe,
    encode_command,
)

__all__ = ["Client", "DeviceError", "LinkError", "error_text", "hex_bytes"]


def hex_bytes(data: bytes) -> str:
    """Return ``data`` as lower-case hex bytes separated by spaces (``"03 00 8b"``)."""
    return data.hex(" ")


def error_text(code: ErrorCode | int) -> str:
    """Return the display text of an error code: ``"E3 motor not ready"``."""
    if isinstance(code, ErrorCode):
        return f"{code.short} {code.label.lower()}"
    return f"unknown error code 0x{code:02x}"


class DeviceError(Exception):
    """The device answered a command with an error response (R0 = 0x00)."""

    def __init__(self, code: ErrorCode | int, command: Command | None = None) -> None:
        self.code: ErrorCode | int = code
        self.command: Command | None = command
        super().__init__(error_text(code))


class LinkError(Exception):
    """No, short or corrupted response, or the port itself failed."""


class Client:
    """A connection to a motorctl device on a serial port (UART or PTY)."""

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        timeout: float = 5.0,
        options: CodecOptions | None = None,
    ) -> None:
        self.port = port
        self.timeout = timeout
        self.options = options if options is not None else CodecOptions()
        self.last_request: bytes = b""
        self.last_response: bytes = b""
        self.sent_at = 0.0  # time.monotonic() when last_request was written
        self._serial = serial.Serial(port, baud, timeout=timeout, write_timeout=timeout)

    # -- lifetime -------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._serial.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- raw I/O --------------------------------------------------------------------------

    def send_bytes(self, data: bytes) -> None:
        """Write ``data`` as is (any length); it becomes ``last_request``."""
        self.last_request = bytes(data)
        self.sent_at = time.monotonic()
        try:
            self._serial.write(data)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"cannot write {hex_bytes(data)} to {self.port}: {exc}") from exc

    def send_frame(self, frame: bytes) -> None:
        """Write one complete 10-byte frame (checksum included, not checked)."""
        if len(frame) != FRAME_LEN:
            raise ValueError(f"a frame is {FRAME_LEN} bytes, got {len(frame)}")
        self.send_bytes(frame)

    def read_raw(self, n: int, timeout: float | None = None) -> bytes:
        """Read up to ``n`` bytes, waiting at most ``timeout`` seconds in total.

        Returns fewer than ``n`` bytes if the time runs out; the bytes read become
        ``last_response``.
        """
        wait = self.timeout if timeout is None else timeout
        try:
            if self._serial.timeout != wait:
                self._serial.timeout = wait
            data = bytes(self._serial.read(n))
        except (serial.SerialException, OSError) as exc:
            self.last_response = b""
            raise LinkError(f"cannot read from {self.port}: {exc}") from exc
        self.last_response = data
        return data

    def read_response(self, timeout: float | None = None) -> Response:
        """Read and decode one 5-byte response.

        Raises :class:`LinkError` on silence, a short read or a bad checksum.
        """
        wait = self.timeout if timeout is None else timeout
        data = self.read_raw(RESPONSE_LEN, wait)
        sent = f" to {hex_bytes(self.last_request)}" if self.last_request else ""
        if not data:
            raise LinkError(f"no response{sent} within {wait:g} s")
        if len(data) < RESPONSE_LEN:
            raise LinkError(
                f"short response{sent}: got {hex_bytes(data)} "
                f"({len(data)} of {RESPONSE_LEN} bytes) within {wait:g} s"
            )
        try:
            return decode_response(data, self.options)
        except ResponseError as exc:
            raise LinkError(f"bad response{sent}: got {hex_bytes(data)} ({exc})") from exc

    def transact(self, cmd: Command, timeout: float | None = None) -> Response:
        """Send ``cmd`` and return its response (error responses included, not raised)."""
        self.send_frame(encode_command(cmd, self.options))
        try:
            return self.read_response(timeout)
        except LinkError as exc:
            raise LinkError(f"{describe(cmd)}: {exc}") from exc

    # -- typed commands -------------------------------------------------------------------

    def call(self, cmd: Command) -> Reading:
        """Send ``cmd`` and return its answer read for it (the table's reading: ``value``,
        ``text``); :class:`DeviceError` on an error answer. An answer the table says may be
        held (WaitMoved) is waited for as long as the command says, plus the client's
        timeout."""
        held = cmd.spec.answer.held
        timeout = getattr(cmd, held) / 1000.0 + self.timeout if held else None
        return decode_answer(cmd, self._call(cmd, timeout))

    def _call(self, cmd: Command, timeout: float | None = None) -> Response:
        resp = self.transact(cmd, timeout)
        if not resp.ack:
            code = resp.error_code
            raise DeviceError(code if code is not None else resp.payload[0], cmd)
        return resp

    def init_move(
        self, motor: int, direction: bool, speed: int = 0, acc: int = 0, dec: int = 0
    ) -> None:
        """InitMove: home ``motor`` towards its end stop in ``direction``."""
        self._call(InitMove(motor, direction, speed, acc, dec))

    def move_to(
        self,
        motor: int,
        position: int,
        speed: int = 0,
        acc: int = 0,
        dec: int = 0,
        direction: bool = True,
    ) -> None:
        """MoveTo: queue a move of ``motor`` to the absolute ``position``."""
        self._call(MoveTo(motor, direction, position, speed, acc, dec))

    def wait_moved(self, motor: int, timeout_ms: int) -> None:
        """WaitMoved: block until ``motor`` is idle; the device answers E3 after ``timeout_ms``.

        The read waits ``timeout_ms`` plus the client's own timeout.
        """
        self.call(WaitMoved(motor, timeout_ms))

    def is_ready(self, motor: int) -> bool:
        """IsReady: True when ``motor`` is idle with an empty queue."""
        return self._call(IsReady(motor)).as_bool

    def move(self, motor: int, direction: bool, speed: int = 0, acc: int = 0, dec: int = 0) -> None:
        """Move: run ``motor`` continuously in ``direction`` until stopped."""
        self._call(Move(motor, direction, speed, acc, dec))

    def stop(self, motor: int, hard: bool = False) -> None:
        """StopMove: stop ``motor`` (with its ramp unless ``hard``) and empty its queue."""
        self._call(StopMove(motor, hard))

    def position(self, motor: int) -> int:
        """GetAbsPos: the current position of ``motor`` (signed 24 bit)."""
        return self._call(GetAbsPos(motor)).as_position

    def set_pin(self, pin: int, high: bool) -> None:
        """SetPin: drive output ``pin`` high or low."""
        self._call(SetPin(pin, high))

    def get_pin(self, pin: int) -> bool:
        """GetPin: True when ``pin`` reads high."""
        return self._call(GetPin(pin)).as_bool

    def config_pin(self, pin: int, output: bool) -> None:
        """ConfigPin: make ``pin`` an output (True) or an input (False)."""
        self._call(ConfigPin(pin, output))

    def save_home(self, motor: int) -> None:
        """SaveHome: store the current position of ``motor`` as its home."""
        self._call(SaveHome(motor))

    def go_home(self, motor: int) -> None:
        """GoHome: queue a move of ``motor`` to its saved home."""
        self._call(GoHome(motor))

    def save_waypoint(self, motor: int) -> int:
        """SaveWayPoint: store the current position; returns the waypoint's number."""
        return self._call(SaveWayPoint(motor)).payload[0]

    def move_to_waypoint(
        self, motor: int, waypoint: int, speed: int = 0, acc: int = 0, dec: int = 0
    ) -> None:
        """MoveToWayPoint: queue a move of ``motor`` to saved ``waypoint``."""
        self._call(MoveToWayPoint(motor, waypoint, speed, acc, dec))

    def dc_move(self, direction: bool, time_ms: int, hiz: bool) -> None:
        """DcMove: run the DC motor ``time_ms`` in ``direction``, then coast (hiz) or brake."""
        self._call(DcMove(direction, time_ms, hiz))
