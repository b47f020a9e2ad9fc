"""Stand-ins at the gpiod backend's own seams where no kernel device can exist here: a line
request that records the levels written to it, and a kernel PWM class laid out in a folder.
(The GPIO side itself runs on gpio-sim in the hardware tier.)"""

from __future__ import annotations

from pathlib import Path

from motorctl.hal.backends.gpiod.chip import Edge, LineRequest, LineSettings


class RecordingRequest(LineRequest):
    """A request of output lines on /dev/gpiochip0: ``levels`` holds what was written."""

    def __init__(self) -> None:
        super().__init__("/dev/gpiochip0", {})
        self.levels: dict[int, bool] = {}

    def set_values(self, values: dict[int, bool]) -> None:
        self.levels.update(values)

    def get_values(self, offsets: list[int]) -> list[bool]:
        return [self.levels.get(o, False) for o in offsets]

    def reconfigure(self, offset: int, settings: LineSettings) -> None:
        raise AssertionError("an output request is never reconfigured here")

    def fileno(self) -> int:
        return -1

    def read_events(self) -> list[Edge]:
        return []

    def release(self) -> None:
        pass


def pwm_sysfs(root: Path, chip: int = 0, channel: int = 1) -> Path:
    """``root`` laid out as the kernel's PWM class after ``pwmchip<chip>/export`` of
    ``channel``: the channel's folder with period, duty_cycle and enable (returned)."""
    folder = root / f"pwmchip{chip}"
    folder.mkdir()
    (folder / "export").write_text("")
    pwm = folder / f"pwm{channel}"
    pwm.mkdir()
    for name in ("period", "duty_cycle", "enable"):
        (pwm / name).write_text("0")
    return pwm
