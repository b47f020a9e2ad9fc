"""The status document as JSON, encoded part by part: a part that has not changed since the
last document keeps its encoding.

Encoding the whole document was half of a status read's cost (its floats above all: each
takes several times an integer's work), and while motors step only some parts change from
one read to the next (the motors, the step counters, the clock), not the link, the state
file, the executor, the errors, the pins. :class:`DocumentEncoder` gives exactly
``json.dumps(doc, sort_keys=True)`` (the default separators, ASCII only), put together from
the encodings of the document's top-level parts: a part equal (``==``, compared in C) to the
one encoded under its name last time reuses that encoding. (Finer parts, a motor's fields
each, cost more in Python's bookkeeping than their encoding saves.)

What that takes of the document (daemon/status/document.py keeps it): its parts are its own
(built for it, or never changed once made: the real-time report), so a part kept from the
last document still holds what was encoded; and each field keeps its type (a count is an
int, a time a float, a flag a bool, as docs/status.md gives them), so equal values encode
alike (``1``, ``1.0`` and ``true`` are equal in Python, not in JSON). One pair of equal
values stays: ``-0.0`` and ``0.0`` (a speed rounded to 0.1 step/s), encoded as the one seen
first until the part changes otherwise: the same number to any JSON reader.

Owner: one thread (the status server's); an encoder is not shared.
"""

from __future__ import annotations

import json
import math
from json.encoder import encode_basestring_ascii
from typing import Any

#: ``json.dumps(value, sort_keys=True)`` without making an encoder at every call
_encode = json.JSONEncoder(sort_keys=True).encode


def encode(value: Any) -> str:
    """``json.dumps(value, sort_keys=True)``; an int, a finite float or a string (the
    clock's fields, every read) without the encoder's set-up, as the encoder writes them."""
    kind = type(value)
    if kind is float and math.isfinite(value):
        return float.__repr__(value)
    if kind is int:
        return int.__repr__(value)
    if kind is str:
        return encode_basestring_ascii(value)
    return _encode(value)


class DocumentEncoder:
    """``json.dumps(doc, sort_keys=True)`` of successive status documents, each top-level
    part encoded again only when it changed (see the module's doc)."""

    def __init__(self) -> None:
        #: name -> (the value last encoded, '"name": ' and its JSON)
        self._last: dict[str, tuple[Any, str]] = {}

    def encode(self, doc: dict[str, Any]) -> bytes:
        return self.text(doc).encode()

    def text(self, doc: dict[str, Any]) -> str:
        last = self._last
        out = []
        for name in sorted(doc):
            value = doc[name]
            hit = last.get(name)
            if hit is None or hit[0] != value:
                hit = last[name] = (value, f"{encode_basestring_ascii(name)}: {encode(value)}")
            out.append(hit[1])
        return "{" + ", ".join(out) + "}"
