"""Fixtures of the status tests: a status server answering with the metrics tests' document."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from motorctl.daemon.status.server import StatusServer
from tests.daemon.status.test_metrics import DOC


@pytest.fixture
def doc_server(tmp_path: Path) -> Iterator[StatusServer]:
    """A StatusServer in ``tmp_path`` whose every document is a fresh copy of ``DOC``."""
    server = StatusServer(
        tmp_path / "status.sock", lambda histogram=False: json.loads(json.dumps(DOC))
    )
    server.start()
    try:
        yield server
    finally:
        server.close()
