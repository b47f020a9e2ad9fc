"""Pick the contract's backend: the mock (default), or gpiod on gpio-sim when the VM tier
sets MOTORCTL_CONTRACT=gpiod (hwtest/run)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from tests.contract.harness import Harness, MockHarness


@pytest.fixture
def harness() -> Iterator[Harness]:
    h: Harness
    if os.environ.get("MOTORCTL_CONTRACT", "mock") == "gpiod":
        from hwtest.gpiod_harness import GpiodHarness

        h = GpiodHarness()
    else:
        h = MockHarness()
    try:
        yield h
    finally:
        h.close()
