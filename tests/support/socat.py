"""A serial device that can go away and come back: socat's two linked PTYs at fixed paths,
the daemon's (``--port``) and the host's, torn down and made again as a USB adapter is
unplugged and plugged back in. Tests that need socat are marked ``needs_socat``."""

from __future__ import annotations

import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from tests.support.wait import until

SOCAT = shutil.which("socat")
needs_socat = pytest.mark.skipif(
    SOCAT is None,
    reason="SOCAT IS MISSING, so the serial device reconnect tests did NOT run: "
    "apt-get install socat (make test installs it when run as root)",
)


class PtyPair:
    """socat's two linked PTYs at fixed paths: ``device`` (the daemon's) and ``host``."""

    def __init__(self, device: Path, host: Path, log: Path) -> None:
        self.device, self.host, self.log = device, host, log
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> PtyPair:
        assert SOCAT is not None
        with open(self.log, "ab") as err:
            self.proc = subprocess.Popen(
                [SOCAT, f"pty,raw,echo=0,link={self.device}", f"pty,raw,echo=0,link={self.host}"],
                stderr=err,
            )
        until("socat's PTYs", lambda: self.device.exists() and self.host.exists())
        return self

    def stop(self) -> None:
        """Tear the pair down, as a USB adapter is pulled out: its PTYs are gone, and their
        names first (socat closes a PTY before it removes its link: a daemon opening the
        path again in between would open the next PTY made with that number, anyone's;
        tests/docs/test_messages.py, ``Session.unplug``)."""
        for link in (self.device, self.host):
            link.unlink(missing_ok=True)
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(10)
        self.proc = None
