"""File-system helpers for tests: a directory made read-only for real (EROFS or EACCES), a
small tmpfs that can be filled up for real (ENOSPC), the checkout's reach for another user."""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import REPO


@contextlib.contextmanager
def read_only(path: Path) -> Iterator[None]:
    """Make ``path`` unwritable for this process while inside the block.

    As root, permissions do not stop writes: a read-only bind mount over the directory does
    (skips when mounting is not permitted). Otherwise mode 0555 does.

    The kernel refuses to make a mount read-only while a file is open for writing through
    it ("mount point is busy"): a running daemon may be in the middle of writing its state
    file. That write ends within milliseconds, so the remount is retried until it succeeds
    or ``REMOUNT_DEADLINE_S`` has passed.
    """
    if os.geteuid() != 0:
        mode = path.stat().st_mode
        path.chmod(0o555)
        try:
            yield
        finally:
            path.chmod(mode)
        return
    bind = subprocess.run(["mount", "--bind", str(path), str(path)], capture_output=True)
    if bind.returncode != 0:
        pytest.skip(f"cannot bind-mount {path} read-only: {bind.stderr.decode().strip()}")
    try:
        _remount_read_only(path)
        yield
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)


REMOUNT_DEADLINE_S = 10.0
_RETRY_S = 0.005


def _remount_read_only(path: Path) -> None:
    deadline = time.monotonic() + REMOUNT_DEADLINE_S
    while True:
        ro = subprocess.run(["mount", "-o", "remount,ro,bind", str(path)], capture_output=True)
        if ro.returncode == 0:
            return
        err = ro.stderr.decode().strip()
        if "busy" not in err or time.monotonic() >= deadline:
            raise AssertionError(f"cannot remount {path} read-only: {err}")
        time.sleep(_RETRY_S)  # a writer still has a file open there; it closes it soon


@contextlib.contextmanager
def small_tmpfs(path: Path, size: str = "1m") -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``path`` (made if missing) while inside the block; skips
    when mounting is not permitted (not root)."""
    path.mkdir(parents=True, exist_ok=True)
    mount = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(path)],
        capture_output=True,
    )
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs at {path}: {mount.stderr.decode().strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)


def fill(directory: Path, limit: int = 16 << 20) -> Path:
    """Fill the (small) file system of ``directory`` until ENOSPC, writing at most ``limit``
    bytes; the filler file (remove it to make room again)."""
    filler = directory / "filler"
    block = bytes(4096)
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        for _ in range(limit // len(block)):
            try:
                os.write(fd, block)
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
                return filler
    finally:
        os.close(fd)
    raise AssertionError(f"{directory} still has room after {limit} bytes: not a small tmpfs")


#: this checkout's motorctl imported by this interpreter
IMPORT = (sys.executable, "-c", "import motorctl")


@functools.cache
def _nobody_cannot_import() -> str:
    """Why user nobody cannot import this checkout's motorctl ("" when it can)."""
    done = subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *IMPORT],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
    )
    return "" if done.returncode == 0 else done.stderr.strip().splitlines()[-1]


def need_checkout_open_to_others() -> None:
    """Skip, saying why, when user nobody (as whom these tests run motorctl) cannot import
    this checkout's motorctl: a clone in a private folder (``mktemp -d``'s 0700) would
    otherwise fail such a test with ``No module named 'motorctl'``, saying nothing of why."""
    why = _nobody_cannot_import()
    if why:
        pytest.skip(
            f"user nobody cannot import motorctl from {REPO} ({why}): a folder above it is "
            "closed to other users; clone into a folder others may enter"
        )
