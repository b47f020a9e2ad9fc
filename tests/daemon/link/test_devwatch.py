"""A serial device that is away (daemon/link/devwatch.py), without a link: the folders
watched follow the links of its path; its loss and its absence at start said once, with
their fields, and the schedule started; a return found by the schedule or by the watch.
(The link serving a device that goes and comes: test_serialport.py, test_serialport_e2e.py.)"""

from __future__ import annotations

import errno
import logging
from collections import Counter
from pathlib import Path

import pytest

from motorctl.daemon.link import devwatch
from motorctl.daemon.link.devwatch import DeviceReturn, PathWatch, watched_names
from motorctl.daemon.link.serialport import Backoff, DeviceError


def test_the_folders_watched_follow_the_links(tmp_path: Path) -> None:
    (tmp_path / "by-id").mkdir()
    (tmp_path / "dev").mkdir()
    link = tmp_path / "by-id" / "usb-x"
    link.symlink_to("../dev/ttyUSB0")  # relative, as udev's; its target not there yet
    assert watched_names(str(link)) == {
        str(tmp_path / "by-id"): {"usb-x"},
        str(tmp_path / "dev"): {"ttyUSB0"},
    }
    missing = tmp_path / "serial" / "by-id" / "usb-y"  # two folders missing
    assert watched_names(str(missing)) == {str(tmp_path): {"serial"}}


class Device:
    """A device for DeviceReturn: each open raises the next error given, then works."""

    def __init__(self, path: str, errors: list[int]) -> None:
        self.path = path
        self.errors = list(errors)
        self.opens = 0
        self.closes = 0

    def open(self) -> int:
        self.opens += 1
        if self.errors:
            code = self.errors.pop(0)
            raise DeviceError(f"{self.path}: error {code}", code)
        return 42

    def close(self) -> None:
        self.closes += 1


class Notice:
    """A watch that reports news when told to (no descriptor of its own)."""

    def __init__(self) -> None:
        self.fd: int | None = None
        self.armed = 0
        self.news = False

    def arm(self) -> bool:
        self.armed += 1
        return True

    def changed(self) -> bool:
        news, self.news = self.news, False
        return news

    def disarm(self) -> None:
        self.armed = 0

    def close(self) -> None:
        pass


def test_a_folder_made_while_the_watch_is_set_is_watched_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """mkdir -p of serial/by-id can fall between reading the path and watching its nearest
    folder: no event reaches anyone, so the watch reads the path again once set, and the
    link made next in the new folder is news."""
    by_id = tmp_path / "serial" / "by-id"
    path = by_id / "usb-z"
    real = devwatch.watched_names
    raced: list[bool] = []

    def racing(p: str) -> dict[str, set[str]]:
        out = real(p)
        if not raced:  # the folders appear after the reading, before the watch
            raced.append(True)
            by_id.mkdir(parents=True)
        return out

    monkeypatch.setattr(devwatch, "watched_names", racing)
    watch = PathWatch(str(path))
    try:
        assert watch.arm()
        assert not watch.changed()
        path.symlink_to("/dev/null")
        assert watch.changed()
    finally:
        watch.close()


def test_a_lost_device_is_closed_counted_said_once_and_tried_on_the_schedule(
    caplog: pytest.LogCaptureFixture,
) -> None:
    device = Device("/dev/ttyUSB9", [errno.ENOENT, errno.EACCES, errno.EACCES])
    counters: Counter[str] = Counter()
    notice = Notice()
    away = DeviceReturn(device, notice, Backoff(0.05, 0.2), counters)
    caplog.set_level(logging.DEBUG, "motorctl.link")
    away.lost("it hung up", 10.0)
    assert device.closes == 1 and counters["device_lost"] == 1 and notice.armed == 1
    (lost,) = caplog.records
    assert lost.levelno == logging.WARNING and lost.__dict__["EVENT"] == "device_lost"
    assert lost.getMessage().startswith(
        "serial device /dev/ttyUSB9 is gone (it hung up); motors and positions are kept"
    )
    assert away.wait_s(10.0) == pytest.approx(0.05)
    assert away.look([], 10.04) is None and device.opens == 0  # not yet time
    assert away.look([], 10.05) is None  # not there yet: debug only
    assert away.look([], 10.16) is None  # there, not usable: a warning, once
    assert away.look([], 10.37) is None  # the same reason: not said again
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2 and "error 13" in warnings[1].getMessage()
    assert away.wait_s(10.37) == pytest.approx(0.2)  # the schedule's longest pause
    notice.news = True  # something changed on the path: tried at once
    assert away.look([], 10.38) is None  # no descriptor to have news on: the schedule
    assert away.look([], 10.57) == 42
    assert counters["device_reopened"] == 1 and counters["reopen_attempts"] == 4
    assert notice.armed == 0  # back: not watched any more
    assert (
        caplog.records[-1]
        .getMessage()
        .startswith("serial device /dev/ttyUSB9 is back after 0.6 s (4 attempts)")
    )


def test_a_device_not_there_at_start_is_awaited_and_said_to_appear(
    caplog: pytest.LogCaptureFixture,
) -> None:
    device = Device("/dev/ttyACM0", [])
    counters: Counter[str] = Counter()
    away = DeviceReturn(device, None, Backoff(0.05, 1.0), counters)
    caplog.set_level(logging.INFO, "motorctl.link")
    away.awaited(0.0)
    assert not away.ever_open and device.closes == 0 and counters["device_lost"] == 0
    assert caplog.records[0].__dict__["EVENT"] == "device_awaited"
    assert "trying every 1000 ms at most" in caplog.records[0].getMessage()
    assert away.fds == [] and away.look([], 0.05) == 42
    assert away.ever_open and counters["device_reopened"] == 0  # it appeared: not a return
    assert caplog.records[-1].__dict__["EVENT"] == "device_appeared"
