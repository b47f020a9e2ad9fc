"""The daemon's trace: every byte run of the link, timestamped, to a rotating pcapng file.

The format is :mod:`motorctl.protocol.capture`'s (docs/trace.md); this module is its file
side for the daemon: opening, writing, rotating, bounding.

Threads: the link thread calls :meth:`TraceRecorder.received` and :meth:`TraceRecorder.sent`
with each byte run and the link's own clock reading; they encode the run (about a
microsecond) and append it to a memory buffer under a lock held only for the append. The
recorder's own thread (``motorctl-trace``) takes the buffer every ``flush_s`` and writes it,
so the link thread never waits for the disk. :meth:`TraceRecorder.status` may be called from
any thread (it copies counters). :meth:`TraceRecorder.open` and :meth:`TraceRecorder.close`
run on the main thread, at start and at exit.

Bounds: a file grows to at most ``max_bytes``, then rotates (``FILE`` -> ``FILE.1`` ->
``FILE.2`` ...), ``files`` files in all; each file's header names this run's session and
the file's part number (1, 2, ...), so a reader notices the parts rotation deleted. The
memory buffer holds at most ``buffer_limit`` bytes: beyond it runs are left out and
counted, and the next run recorded carries the count (``epb_dropcount``). A write error is
logged once, counted, and the trace goes on with the next flush: it never stops the link.
"""

from __future__ import annotations

import errno
import logging
import os
import platform
import stat
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from motorctl.daemon.state.files import clear_the_way, kind, open_for_writing
from motorctl.protocol.capture.format import CaptureInfo, Direction
from motorctl.protocol.capture.writer import RecordEncoder, header

log = logging.getLogger("motorctl.trace")

FLUSH_S = 0.2
BUFFER_LIMIT = 4 << 20

_IN, _OUT = int(Direction.TO_DEVICE), int(Direction.TO_HOST)


def rotated(path: Path, index: int) -> Path:
    """``path`` for index 0, else ``path.N``."""
    return path if index == 0 else path.with_name(f"{path.name}.{index}")


class TraceRecorder:
    """Records the link's byte runs (the link's ``recorder``)."""

    def __init__(
        self,
        path: Path,
        info: CaptureInfo,
        max_bytes: int,
        files: int,
        clock_origin: float,
        wall_origin_ns: int | None = None,
        *,
        flush_s: float = FLUSH_S,
        buffer_limit: int = BUFFER_LIMIT,
    ) -> None:
        self.path = path
        self.info = info
        self.max_bytes = max_bytes
        self.files = files
        self.flush_s = flush_s
        self.buffer_limit = buffer_limit
        self._t0 = clock_origin
        self._wall0 = time.time_ns() if wall_origin_ns is None else wall_origin_ns
        self._os_name = f"{platform.system()} {platform.release()}"
        self.session = info.session or os.urandom(6).hex()  # this run's files, numbered:
        self.part = 0  # the part being written (1 = the session's first file)
        self._head_size = 0
        self._enc = RecordEncoder()
        self._lock = threading.Lock()
        self._buf = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._file: Any = None
        self._size = 0
        self._failing = False
        # link thread's
        self.runs = 0
        self.dropped_runs = 0
        self._owed_drops = 0
        # writer thread's
        self.bytes_written = 0
        self.rotations = 0
        self.write_errors = 0
        self.lost_bytes = 0

    # -- main thread -----------------------------------------------------------------------
    def open(self) -> None:
        """Start a new file (the previous ones rotate away) and the writer thread; OSError
        if the file cannot be created (the caller names it to the user)."""
        _not_a_device(self.path)
        clear_the_way(self.path)  # not a trace of ours: set aside, not rotated
        self._rotate_files()
        self._file = _create(self.path)  # closed in close()
        self._write_header()
        self._thread = threading.Thread(target=self._run, name="motorctl-trace", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Write what is buffered and close the file."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)
            self._thread = None
        self._flush()
        if self._file is not None:
            self._file.close()
            self._file = None

    # -- link thread ------------------------------------------------------------------------
    def received(self, data: bytes, t: float) -> None:
        """Bytes read from the host at link-clock time ``t``."""
        self._add(_IN, data, t)

    def sent(self, data: bytes, t: float) -> None:
        """Bytes written to the host at link-clock time ``t``."""
        self._add(_OUT, data, t)

    def _add(self, direction: int, data: bytes, t: float) -> None:
        if len(self._buf) >= self.buffer_limit:
            self.dropped_runs += 1
            self._owed_drops += 1
            return
        ts = self._wall0 + round((t - self._t0) * 1e9)  # as capture.ns_from
        block = self._enc.encode(ts, direction, data, self._owed_drops)
        self._owed_drops = 0
        self.runs += 1
        with self._lock:
            self._buf += block

    # -- writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.wait(self.flush_s):
            self._flush()

    def _flush(self) -> None:
        with self._lock:
            if not self._buf:
                return
            data, self._buf = self._buf, bytearray()
        try:
            self._write(memoryview(data))
        except OSError as exc:
            self.write_errors += 1
            self.lost_bytes += len(data)
            if not self._failing:
                self._failing = True
                log.error(
                    "trace %s: cannot write (%s); records are lost until it works again",
                    self.path,
                    exc.strerror or exc,
                )
            return
        if self._failing:
            self._failing = False
            log.info("trace %s: writing again", self.path)

    def _write(self, data: memoryview) -> None:
        if self._file is None:
            self._start_file()
        while data:
            room = self.max_bytes - self._size
            cut = len(data) if len(data) <= room else self._fits(data, room)
            if cut == 0 and self._size == self._head_size:  # one block larger than a file
                cut = int.from_bytes(data[4:8], "little")
            if cut:
                self._put(data[:cut])
                data = data[cut:]
            if data:
                self._file.close()
                self._file = None
                self.rotations += 1
                self._start_file()

    def _put(self, data: memoryview) -> None:
        self._size += len(data)
        self.bytes_written += len(data)
        while data:
            n = self._file.write(data)
            data = data[n:]

    @staticmethod
    def _fits(data: memoryview, room: int) -> int:
        """The length of the whole blocks at the start of ``data`` that fit in ``room``."""
        pos = 0
        while pos + 8 <= len(data):
            total = int.from_bytes(data[pos + 4 : pos + 8], "little")
            if pos + total > room:
                break
            pos += total
        return pos

    def _start_file(self) -> None:
        clear_the_way(self.path)
        self._rotate_files()
        self._file = _create(self.path)
        self._write_header()

    def _write_header(self) -> None:
        """The next part's header: its session and number let a reader notice a part that
        rotation deleted (or that was not given) and a session whose start is gone."""
        self.part += 1
        info = replace(self.info, session=self.session, part=self.part)
        head = header(info, os_name=self._os_name)
        self._file.write(head)
        self._size = self._head_size = len(head)

    def _rotate_files(self) -> None:
        """``FILE.N-2`` to ``FILE.N-1``, ..., ``FILE`` to ``FILE.1``; the oldest goes. Only
        the daemon's own files are renamed or removed: anything else at one of these names
        (another user's file, a hard link, a link, a folder, a FIFO, ...) is set aside as
        at ``FILE`` (daemon/state/files.py), never deleted or renamed over."""
        oldest = rotated(self.path, self.files - 1)
        clear_the_way(oldest)
        if os.path.lexists(oldest):
            log.info(
                "trace %s: %s rotated away (the oldest of %d files; readers of the rest say "
                "which part is missing)",
                self.path,
                oldest,
                self.files,
            )
        oldest.unlink(missing_ok=True)
        for index in range(self.files - 2, -1, -1):
            src = rotated(self.path, index)
            clear_the_way(src)
            if os.path.lexists(src):
                os.replace(src, rotated(self.path, index + 1))

    def status(self) -> dict[str, object]:
        return {
            "file": str(self.path),
            "runs": self.runs,
            "dropped_runs": self.dropped_runs,
            "bytes_written": self.bytes_written,
            "rotations": self.rotations,
            "write_errors": self.write_errors,
            "lost_bytes": self.lost_bytes,
            "max_file_bytes": self.max_bytes,
            "files": self.files,
            "session": self.session,
            "part": self.part,
        }


def _not_a_device(path: Path) -> None:
    """OSError when ``path`` is a device, or a link to one (``--trace /dev/null``,
    ``/dev/stdout``): only root makes those, so it is no one's trap to set aside, and
    neither renaming it (set aside, rotated) nor writing to it is what anyone wants."""
    try:
        mode = os.stat(path).st_mode  # through a link: never opened
    except OSError:
        return
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        through = " (through a symbolic link)" if os.path.islink(path) else ""
        raise OSError(
            errno.ENODEV, f"{path} is {kind(mode)}{through}, not a file; a trace is a file"
        )


def _create(path: Path) -> Any:
    """A new, empty trace file at ``path`` (0640 less the umask, like the state), opened
    as the daemon opens every file it writes (daemon/state/files.py: never through a link, never
    a FIFO or a device; what stands there is set aside). OSError when it cannot."""
    fd = open_for_writing(path, 0o640, os.O_WRONLY)
    try:
        os.ftruncate(fd, 0)
    except OSError:
        os.close(fd)
        raise
    return open(fd, "wb", buffering=0)  # the recorder closes it
