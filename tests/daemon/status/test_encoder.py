"""daemon/status/encoder.py: successive status documents encoded part by part are exactly
``json.dumps(doc, sort_keys=True)``: a part that changed is encoded again (a nested value,
a part gone, a part new), one that did not keeps its encoding; the shortcuts for a bare
number or string agree with json.dumps (NaN and the infinities go to json's own way)."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from motorctl.daemon.status.encoder import DocumentEncoder, encode


def dumps(doc: Any) -> bytes:
    return json.dumps(doc, sort_keys=True).encode()


def test_a_changed_part_is_encoded_again_and_an_unchanged_one_kept() -> None:
    enc = DocumentEncoder()
    first = {"motors": [{"position": 1, "speed": 2.5}], "link": {"peer": "open"}, "n": 3}
    assert enc.encode(first) == dumps(first)
    kept = enc._last["link"][1]
    second = {"motors": [{"position": 2, "speed": 2.5}], "link": {"peer": "open"}, "n": 3}
    assert enc.encode(second) == dumps(second)  # the nested position changed
    assert enc._last["link"][1] is kept  # equal: not encoded again
    third = {"motors": [], "extra": "é\n", "n": 4.0}  # parts gone and new, a type changed
    assert enc.encode(third) == dumps(third)
    assert enc.encode({}) == b"{}"


def test_a_part_changed_in_place_is_seen_when_the_document_is_new() -> None:
    """A part kept from the last document and changed since would keep its old encoding
    (the documents' own parts are never changed: daemon/status/document.py); a new
    document built from a changed source is a new value and is encoded again."""
    enc = DocumentEncoder()
    source = {"a": 1}
    assert enc.encode({"part": dict(source)}) == b'{"part": {"a": 1}}'
    source["a"] = 2
    assert enc.encode({"part": dict(source)}) == b'{"part": {"a": 2}}'


@given(
    st.one_of(
        st.integers(),
        st.floats(allow_nan=True, allow_infinity=True),
        st.text(),
        st.booleans(),
        st.none(),
    )
)
def test_a_bare_value_is_encoded_as_json_dumps_does(value: Any) -> None:
    assert encode(value) == json.dumps(value, sort_keys=True)


#: a status-like value: each field keeps its type from one document to the next (an int
#: stays an int), as the status document's do (docs/status.md)
leaf = st.one_of(st.integers(-5, 5), st.sampled_from([0.5, 1.25, -2.75]), st.text(max_size=3))
value = st.recursive(
    leaf,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=8,
)


@settings(max_examples=60)
@given(st.lists(st.dictionaries(st.sampled_from("abcdef"), value, max_size=6), max_size=6))
def test_successive_documents_are_exactly_json_dumps(docs: list[dict[str, Any]]) -> None:
    enc = DocumentEncoder()
    for doc in docs:
        assert enc.encode(doc) == dumps(doc)
