"""Run a command as systemd would with Type=notify, on a fake NOTIFY_SOCKET, and check it.

Usage: notify_listener.py SOCKET USER -- COMMAND...   (run as root inside the test root)

Waits for READY=1, asks the daemon a question with the motorctl CLI as USER, checks the
PTY's mode and group, waits for a STATUS= line, sends SIGTERM and expects STOPPING=1 and
exit status 0, and its log to say it ran the compiled step core and sent its notifications
through NOTIFY_SENDER (``systemd-python``, the default, or ``built-in``: the daemon's own
sender, without python3-systemd, which the package only recommends). Every wait has a
deadline (NOTIFY_DEADLINE_S, default 30 s; longer for a root run under qemu-user). Exit
status 0 when all held.
"""

from __future__ import annotations

import grp
import os
import pwd
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

DEADLINE_S = float(os.environ.get("NOTIFY_DEADLINE_S", "30"))
SENDER = os.environ.get("NOTIFY_SENDER", "systemd-python")


def main() -> int:
    path, user = sys.argv[1], sys.argv[2]
    cmd = sys.argv[sys.argv.index("--") + 1 :]
    pw = pwd.getpwnam(user)
    if os.path.exists(path):
        os.unlink(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    os.chown(path, pw.pw_uid, pw.pw_gid)
    env = {"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "NOTIFY_SOCKET": path, "LANG": "C.UTF-8"}
    err = open("/run/motorctl/motorctld.stderr", "wb")  # noqa: SIM115
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
    seen: list[str] = []

    def wait_for(prefix: str) -> str:
        end = time.monotonic() + DEADLINE_S
        for msg in seen:
            if msg.startswith(prefix):
                return msg
        while time.monotonic() < end:
            sock.settimeout(max(0.01, end - time.monotonic()))
            try:
                data = sock.recv(4096).decode()
            except TimeoutError:
                break
            for line in data.splitlines():
                seen.append(line)
                print(f"  notify: {line}")
            for line in data.splitlines():
                if line.startswith(prefix):
                    return line
        raise SystemExit(
            f"no {prefix} within {DEADLINE_S} s; got {seen}; stderr:\n"
            + Path("/run/motorctl/motorctld.stderr").read_text()
        )

    try:
        wait_for("READY=1")
        pty = "/run/motorctl/motorctl.pty"
        st = os.stat(pty)
        mode, group = stat.S_IMODE(st.st_mode), grp.getgrgid(st.st_gid).gr_name
        print(f"  {pty} -> {os.readlink(pty)}: mode {mode:o}, group {group}")
        assert mode == 0o660 and group == user, "the PTY must be 0660 with the service's group"
        out = subprocess.run(
            [
                "setpriv",
                f"--reuid={user}",
                f"--regid={user}",
                "--init-groups",
                "motorctl",
                "-p",
                pty,
                "pos",
                "0",
            ],
            capture_output=True,
            text=True,
            timeout=DEADLINE_S,
            env=env | {"NOTIFY_SOCKET": ""},
        )
        print(f"  motorctl pos 0 -> {out.stdout.strip()} {out.stderr.strip()}")
        assert out.returncode == 0, out
        wait_for("STATUS=")
        proc.send_signal(signal.SIGTERM)
        wait_for("STOPPING=1")
        code = proc.wait(DEADLINE_S)
        assert code == 0, f"exit status {code}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    log = Path("/run/motorctl/motorctld.stderr").read_text()
    print("  stderr:\n    " + "\n    ".join(log.splitlines()))
    sent = f"systemd notifications through {SENDER}"
    assert sent in log, f"the log does not say '{sent}'"
    assert "step core: compiled" in log, "the daemon did not run the compiled step core"
    assert not os.path.exists(pty), "the PTY link was left behind"
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
