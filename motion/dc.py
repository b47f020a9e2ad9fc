"""The DC motor: timed runs that end in brake or coast, on the engine's clock."""

from __future__ import annotations

from motorctl.hal.interfaces import BridgeState, DcBridge


class DcMotor:
    def __init__(self, bridge: DcBridge) -> None:
        self.bridge = bridge
        self.deadline: float | None = None
        self._end = BridgeState.BRAKE

    @property
    def running(self) -> bool:
        return self.deadline is not None

    def run(self, forward: bool, duration_s: float, end: BridgeState, now: float) -> None:
        """Run for ``duration_s`` (replacing any run), then leave the bridge in ``end``.

        A duration of 0 stops at once in ``end``.
        """
        if end not in (BridgeState.BRAKE, BridgeState.COAST):
            raise ValueError("a run ends in BRAKE or COAST")
        self._end = end
        if duration_s <= 0:
            self.deadline = None
            self.bridge.set(end)
            return
        self.bridge.set(BridgeState.FORWARD if forward else BridgeState.REVERSE)
        self.deadline = now + duration_s

    def service(self, now: float) -> None:
        if self.deadline is not None and now >= self.deadline:
            self.deadline = None
            self.bridge.set(self._end)

    def stop(self, end: BridgeState = BridgeState.BRAKE) -> None:
        self.deadline = None
        self.bridge.set(end)
