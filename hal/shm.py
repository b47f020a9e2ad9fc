"""Anonymous shared memory for the daemon and its step executor process (Linux memfd).

A :class:`SharedBlock` is a ``memfd_create`` file mapped into the process: it has no name in
``/dev/shm`` or anywhere else, so nothing has to remove it. The kernel frees it when its last
descriptor is closed and its last mapping unmapped, that is when both processes are gone,
however they end (an orderly exit, an exception, ``kill -9`` of either; the executor also
dies with the daemon, ``PR_SET_PDEATHSIG``). No resource-tracker process is needed, and none
runs (``multiprocessing.shared_memory`` starts one per process that creates or attaches a
block, 13 MB, to unlink names a crash left behind).

The creator hands the block to a child process by descriptor (``subprocess.Popen``'s
``pass_fds`` keeps its number), the child maps it with :meth:`SharedBlock.attach`.

Owners: the process that holds the object; ``buf`` is read and written by both processes
(their own rules of who writes which cell).
"""

from __future__ import annotations

import mmap
import os


class SharedBlock:
    """``size`` bytes of shared memory, zero-filled at creation; ``buf`` is the mapping.

    ``fd`` is the memfd's descriptor (close-on-exec: a child gets it only through
    ``pass_fds``) until :meth:`forget_fd` or :meth:`close`; the mapping does not need it.
    """

    def __init__(self, fd: int, size: int, name: str) -> None:
        self.name = name
        self.size = size
        self.fd: int | None = fd
        self._map: mmap.mmap | None = mmap.mmap(fd, size)  # MAP_SHARED, read and write
        self.buf = memoryview(self._map)

    @classmethod
    def create(cls, size: int, name: str) -> SharedBlock:
        """A new block, labelled ``NAME-PID-RANDOM``: a label only (``/memfd:LABEL`` in
        ``/proc/PID/maps`` and ``/proc/PID/fd``, where tests and people can see who holds
        it), never looked up."""
        name = f"{name}-{os.getpid()}-{os.urandom(4).hex()}"
        fd = os.memfd_create(name, os.MFD_CLOEXEC)
        try:
            os.ftruncate(fd, size)
            return cls(fd, size, name)
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def attach(cls, fd: int, size: int, name: str) -> SharedBlock:
        """Map the block behind an inherited descriptor (the child process). The
        descriptor is closed at once: the mapping keeps the block alive."""
        have = os.fstat(fd).st_size
        if have < size:
            os.close(fd)
            raise ValueError(f"shared block {name} (fd {fd}) has {have} bytes, {size} needed")
        try:
            block = cls(fd, size, name)
        finally:
            os.close(fd)
        block.fd = None
        return block

    def forget_fd(self) -> None:
        """Close the descriptor (the child has its own copy now); the mapping stays."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def close(self) -> None:
        """Unmap (every view of ``buf`` must be released first) and close the descriptor."""
        self.forget_fd()
        if self._map is not None:
            self.buf.release()
            self._map.close()  # BufferError while a view of buf is still held
            self._map = None
