"""Splits a byte stream into 10-byte command frames with the inter-byte gap rule (PROTOCOL §2).

Pure: the caller passes monotonic timestamps. A partial frame is discarded when strictly more
than `gap_s` passes between two of its bytes.
"""

from __future__ import annotations

from motorctl.protocol.codec import FRAME_LEN


class Framer:
    """Collects bytes into FRAME_LEN-byte frames; gap_s <= 0 turns the gap rule off."""

    def __init__(self, gap_s: float) -> None:
        self.gap_s = gap_s
        self.discarded = 0  # partial frames dropped by the gap rule
        self._buf = bytearray()
        self._last = 0.0

    @property
    def pending(self) -> int:
        """Bytes of the partial frame held."""
        return len(self._buf)

    def _gap_passed(self, now: float) -> bool:
        # Compared against last + gap (not now - last > gap) so that expire(deadline()) is
        # exactly on time whatever the float rounding.
        return bool(self._buf) and self.gap_s > 0 and now > self._last + self.gap_s

    def _discard(self) -> None:
        self._buf.clear()
        self.discarded += 1

    def feed(self, data: bytes, now: float) -> list[bytes]:
        """Add bytes that all arrived at `now`; return the frames completed, in order."""
        if not data:
            return []
        if self._gap_passed(now):
            self._discard()
        self._buf += data
        self._last = now
        count = len(self._buf) // FRAME_LEN
        frames = [bytes(self._buf[i * FRAME_LEN : (i + 1) * FRAME_LEN]) for i in range(count)]
        del self._buf[: count * FRAME_LEN]
        return frames

    def expire(self, now: float) -> bool:
        """Discard the partial frame if its gap has passed at `now`; True if it did."""
        if self._gap_passed(now):
            self._discard()
            return True
        return False

    def deadline(self) -> float | None:
        """Time after which the partial frame expires; None if nothing pending or gap off.

        The gap rule is strict: expire(deadline()) still keeps the bytes, any later time drops them.
        """
        if not self._buf or self.gap_s <= 0:
            return None
        return self._last + self.gap_s
