"""Pick the contract's backend: the mock (default), or gpiod on gpio-sim when the VM tier
sets MOTORCTL_CONTRACT=gpiod (hwtest/run).

The contract is a hardware backend's (pins, STEP/DIR lines, end-stop inputs, the H-bridge).
A dSPIN chip is no backend but a layer over one (hal/layers/dspin/): its motors have no
STEP/DIR lines, and its pins and bridge are the backend's. The dSPIN world's conformance is
the protocol's end-to-end suite on docs/examples/dspin.toml (``make test-dspin``,
``MOTORCTL_WORLD=dspin``) and the chip-ramp executor's tests on the chip model."""

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
