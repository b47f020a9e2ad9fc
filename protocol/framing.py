"""Splits a byte stream into 10-byte command frames with the inter-byte gap rule (PROTOCOL §2).

Pure: no clock. The gap is a property of the line as the reader observed it: the caller says
which bytes it read (:meth:`Framer.feed`; bytes read together, or one after another with no
observed idle time between them, are contiguous however late they were read) and how long it
*watched* the line stay silent while it was ready to read (:meth:`Framer.idle`). A partial
frame is discarded once the observed silence since its last byte is strictly more than
``gap_s``. Time in which the reader was busy never counts, so a backlog in the input buffer
never looks like a gap.
"""

from __future__ import annotations

from motorctl.protocol.codec import FRAME_LEN


class Framer:
    """Collects bytes into FRAME_LEN-byte frames; gap_s <= 0 turns the gap rule off."""

    def __init__(self, gap_s: float) -> None:
        self.gap_s = gap_s
        self.discarded = 0  # partial frames dropped by the gap rule
        self._buf = bytearray()
        self._idle = 0.0  # silence observed since the partial frame's last byte

    @property
    def pending(self) -> int:
        """Bytes of the partial frame held."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        """Add bytes contiguous with the partial frame; return the frames completed, in order."""
        if not data:
            return []
        self._idle = 0.0
        if not self._buf and len(data) == FRAME_LEN:  # the usual read: one whole frame
            return [bytes(data)]
        self._buf += data
        count = len(self._buf) // FRAME_LEN
        frames = [bytes(self._buf[i * FRAME_LEN : (i + 1) * FRAME_LEN]) for i in range(count)]
        del self._buf[: count * FRAME_LEN]
        return frames

    def idle(self, seconds: float) -> bool:
        """The line was watched and stayed silent for ``seconds`` more; True if that discarded
        the partial frame (strictly more than ``gap_s`` of silence since its last byte)."""
        if not self._buf or self.gap_s <= 0 or seconds <= 0:
            return False
        self._idle += seconds
        if self._idle > self.gap_s:
            self._buf.clear()
            self._idle = 0.0
            self.discarded += 1
            return True
        return False

    def gap_left(self) -> float | None:
        """Silence still to be watched before the partial frame goes; None if nothing pending
        or the gap rule is off. Exactly this much still keeps the bytes (the rule is strict)."""
        if not self._buf or self.gap_s <= 0:
            return None
        return self.gap_s - self._idle

    def reset(self) -> int:
        """Drop the partial frame unconditionally (the peer went away); the bytes dropped."""
        n = len(self._buf)
        self._buf.clear()
        self._idle = 0.0
        return n
