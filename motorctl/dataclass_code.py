"""The compiled code of the methods ``@dataclass`` writes, made when the package is built.

Python 3.11's ``@dataclass`` writes each method it adds to a class (``__init__``,
``__repr__``, ``__eq__``, ``__hash__``, a frozen class's ``__setattr__`` and
``__delattr__``) as source text and compiles it with ``exec``, one compilation a method (3.13:
one a class), at every start of every process that defines the class. motorctl's records are
dataclasses: a start of motorctld defines some 100 of them in the daemon and 80 in its step
executor's process, and those compilations were the largest part of its imports
(docs/timing.md, "Start-up and status reads").

So the package's build (``setup.py``'s ``build_py``, hence the wheel and the Debian package;
``make`` for a checkout) imports every module of motorctl once, records the text of every
method ``@dataclass`` compiled and its compiled code, and writes them beside this module in
``dataclass_code.<cache tag>.bin`` (``python -m motorctl.dataclass_code --write FOLDER``). A
process that starts (``motorctld``'s launch, the step executor's bootstrap) loads it
(:meth:`CodeCache.load`) and, while it imports its modules (:meth:`CodeCache.use`), has
``@dataclass`` execute the recorded code of a text instead of compiling the text again.

It can never give other code than compiling would: the code is looked up by the method's
whole text, and the file holds the magic number of the interpreter's bytecode (which changes
whenever its compiled code would: the check Python makes of every ``.pyc``), the
optimisation level it was compiled for and a CRC of its contents. A text it does not hold
(a class changed since the build) is compiled, as without it. A file that is absent, made
by another interpreter or for another level (stale), or unreadable or damaged (corrupt) is
not used at all: :attr:`CodeCache.problem` says which, and the daemon logs it as a warning
(daemon/start/main.py; daemon/start/serve.py when it was found in use); every method is then
compiled, as without it.

While :meth:`CodeCache.use` runs, and only then, the ``dataclasses`` module's global name
``exec`` is this module's hook (module globals come before builtins: every other module's
``exec`` is untouched); it is removed again when the block ends, however it ends. The hook
runs exactly the code the built-in would run (the same globals and namespace, the code
compiled from the same text, as ``exec`` compiles it: file ``<string>``, no inherited
``__future__`` flag), so a dataclass another thread defines meanwhile is the same as
without it. Nothing is ever written at run time: the file is made by the build only.

Owners: the thread that loads a :class:`CodeCache` (the main thread of the daemon and of
its step executor's process, during their start) owns it and its counts; the
``dataclasses`` module's ``exec`` name belongs to the one :meth:`CodeCache.use` block
running, and a second one at the same time is refused.
"""

from __future__ import annotations

import builtins
import dataclasses
import importlib.util
import marshal
import mmap
import os
import stat
import sys
import zlib
from array import array
from bisect import bisect_left
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import CodeType
from typing import Any

#: what the file starts with: this format's name and version
FORMAT = b"motorctl dataclass code 1\n"
#: the largest file read (the package's is about half a MiB)
MAX_BYTES = 16 << 20
#: the file name's stem; its full name adds the interpreter's cache tag (``cpython-311``)
STEM = "dataclass_code"


def header(payload: bytes | bytearray | memoryview) -> bytes:
    """The file's header for ``payload``, for this interpreter: the format, the bytecode's
    magic number, the optimisation level (``-O``), the payload's CRC-32."""
    return (
        FORMAT
        + importlib.util.MAGIC_NUMBER
        + bytes([sys.flags.optimize])
        + zlib.crc32(payload).to_bytes(4, "little")
    )


#: the header's length: :func:`header`'s parts
HEADER = len(FORMAT) + len(importlib.util.MAGIC_NUMBER) + 1 + 4
#: per method, in the index: its text's offset and length, its code's offset and length
FIELDS = 4


def default_path() -> Path | None:
    """Where this interpreter's file is, beside this module; None for an interpreter
    without a cache tag (it caches no bytecode either)."""
    tag = sys.implementation.cache_tag
    return None if tag is None else Path(__file__).with_name(f"{STEM}.{tag}.bin")


def compile_method(text: str) -> CodeType:
    """``text`` compiled as ``exec(text, ...)`` in ``dataclasses`` compiles it."""
    return compile(text, "<string>", "exec", dont_inherit=True)


def words(view: memoryview) -> array[int]:
    """``view``'s unsigned 32-bit little-endian integers."""
    found = array("I")
    if found.itemsize != 4:
        raise ValueError("this machine's unsigned int is not 32 bits")
    found.frombytes(view)
    if sys.byteorder == "big":
        found.byteswap()
    return found


class CodeCache:
    """The recorded code of one file, and what a start took from it.

    The file after its header: the number of methods ``n``, the CRC-32 of each method's
    text (UTF-8) in ascending order, then per method :data:`FIELDS` offsets and lengths
    (its text's, its marshalled code's; from the file's start), all unsigned 32-bit little
    endian, then the texts and codes. A method is found by its text's CRC and then compared
    whole; nothing but the file's bytes and that index is held (no text, no code object is
    made before it is asked for), and :meth:`release` lets all of it go."""

    def __init__(
        self, path: Path | None, data: mmap.mmap | bytes = b"", problem: str | None = None
    ) -> None:
        self.path = path
        #: why the file is not used (absent, stale, corrupt); None when it is
        self.problem = problem
        #: the methods whose code came from the file, and those compiled (not in it)
        self.hits = 0
        self.misses = 0
        #: the file was found corrupt while in use (a method's code), not when loaded
        self.failed_in_use = False
        self._view = memoryview(data)
        self._crcs: array[int] = array("I")
        self._index: array[int] = array("I")
        if len(data):
            self._read_index()

    def _read_index(self) -> None:
        view = self._view
        try:
            (n,) = words(view[HEADER : HEADER + 4])
            crcs_end = HEADER + 4 + 4 * n
            index_end = crcs_end + 4 * FIELDS * n
            if index_end > len(view):
                raise ValueError(f"an index of {n} methods does not fit in {len(view)} bytes")
            self._crcs = words(view[HEADER + 4 : crcs_end])
            self._index = words(view[crcs_end:index_end])
            if any(self._crcs[i] > self._crcs[i + 1] for i in range(n - 1)):
                raise ValueError("its index is not in order")
            if any(
                offset < index_end or offset + length > len(view)
                for offset, length in zip(self._index[::2], self._index[1::2], strict=True)
            ):
                raise ValueError("a method's place is outside the file")
        except ValueError as exc:
            self.problem = f"{self.path} is corrupt: {exc}"
            self.release()

    @classmethod
    def load(cls, path: Path | None = None) -> CodeCache:
        """The file at ``path`` (this interpreter's, :func:`default_path`, by default); one
        that cannot be used is empty, with its :attr:`problem`. Never raises for the file."""
        path = default_path() if path is None else path
        if path is None:
            return cls(None, problem="this interpreter caches no bytecode (no cache tag)")
        try:
            data = map_regular(path)
        except FileNotFoundError:
            return cls(path, problem=f"{path} is absent (built by setup.py or make)")
        except OSError as exc:
            return cls(path, problem=f"{path} cannot be read: {exc.strerror or exc}")
        head, payload = bytes(data[:HEADER]), memoryview(data)[HEADER:]
        if not head.startswith(FORMAT) or len(data) < HEADER + 4:
            return cls(path, problem=f"{path} is corrupt: not a {FORMAT.decode().strip()!r} file")
        expected = header(payload)
        if head[: HEADER - 4] != expected[: HEADER - 4]:
            return cls(path, problem=f"{path} is stale: made by another interpreter or -O level")
        if head != expected:
            return cls(path, problem=f"{path} is corrupt: its CRC does not match its contents")
        return cls(path, data)

    def __len__(self) -> int:
        return len(self._crcs)

    def code(self, text: str) -> CodeType | None:
        """The recorded code of ``text``, None when the file has none (counted either way)."""
        key = text.encode()
        crc, crcs, index, view = zlib.crc32(key), self._crcs, self._index, self._view
        i = bisect_left(crcs, crc)
        while i < len(crcs) and crcs[i] == crc:
            at, size, code_at, code_size = index[FIELDS * i : FIELDS * (i + 1)]
            if view[at : at + size] == key:
                try:
                    code = marshal.loads(view[code_at : code_at + code_size])
                except (EOFError, ValueError, TypeError) as exc:
                    code = exc
                if not isinstance(code, CodeType):
                    self.problem = f"{self.path} is corrupt: a method's code: {code}"
                    self.failed_in_use = True
                    self.release()
                    break
                self.hits += 1
                return code
            i += 1
        self.misses += 1
        return None

    def methods(self) -> dict[str, CodeType]:
        """Every text the file holds and its code (to compare two files: marshal's bytes
        for the same code may differ, as it writes an object as shared or not by its
        reference count)."""
        view, index = self._view, self._index
        found = {}
        for i in range(len(self)):
            at, size, code_at, code_size = index[FIELDS * i : FIELDS * (i + 1)]
            found[bytes(view[at : at + size]).decode()] = marshal.loads(
                view[code_at : code_at + code_size]
            )
        return found

    def release(self) -> None:
        """The start's imports are done (or the file is found bad): let the file's bytes
        and index go (about a MiB, which the step executor would otherwise keep locked in
        memory); a later :meth:`use` compiles."""
        self._view = memoryview(b"")
        self._crcs, self._index = array("I"), array("I")

    def summary(self) -> str:
        """One line on what a start took from the file."""
        said = f"{self.hits} methods from {self.path}, {self.misses} compiled"
        return said if self.problem is None else f"{said}: not used, {self.problem}"

    def _exec(self, source: Any, *args: Any, **kwargs: Any) -> None:
        """``exec`` as ``dataclasses`` calls it, with the recorded code of ``source``."""
        if isinstance(source, str):
            code = self.code(source)
            source = compile_method(source) if code is None else code
        builtins.exec(source, *args, **kwargs)

    @contextmanager
    def use(self) -> Iterator[CodeCache]:
        """While the block runs, ``@dataclass`` takes its methods' code from this file."""
        with dataclasses_exec(self._exec):
            yield self


@contextmanager
def dataclasses_exec(hook: Callable[..., None]) -> Iterator[None]:
    """``dataclasses``' ``exec`` is ``hook`` while the block runs (see the module's doc)."""
    names = vars(dataclasses)
    if "exec" in names:
        raise RuntimeError("dataclasses' exec is taken already (a use() block running?)")
    names["exec"] = hook
    try:
        yield
    finally:
        del names["exec"]


def map_regular(path: Path) -> mmap.mmap | bytes:
    """The regular file ``path``, mapped read-only (empty: ``b""``): OSError for anything
    else (a FIFO is not waited on) or one over :data:`MAX_BYTES`. Mapped, not read: a
    buffer of a MiB from malloc, once freed, would raise glibc's threshold for mapping
    large blocks and leave the step executor's later ones (its parameters' receive buffer)
    on the heap, which it then locks."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_BYTES:
            raise OSError(0, f"not a regular file of at most {MAX_BYTES} bytes")
        if info.st_size == 0:
            return b""
        return mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
    finally:
        os.close(fd)


class Recorder:
    """The build's hook: compiles every text ``@dataclass`` executes and keeps its code."""

    def __init__(self) -> None:
        self.codes: dict[str, CodeType] = {}

    def _exec(self, source: Any, *args: Any, **kwargs: Any) -> None:
        if isinstance(source, str):
            code = self.codes.get(source) or compile_method(source)
            self.codes[source] = code
            source = code
        builtins.exec(source, *args, **kwargs)

    @contextmanager
    def use(self) -> Iterator[Recorder]:
        with dataclasses_exec(self._exec):
            yield self

    def payload(self) -> bytes:
        """What the file holds after its header (:class:`CodeCache`'s layout; the methods
        by their texts' CRC, then their texts)."""
        keys = sorted((zlib.crc32(text.encode()), text.encode(), text) for text in self.codes)
        n = len(keys)
        at = HEADER + 4 + 4 * n + 4 * FIELDS * n
        index, blob = array("I"), bytearray()
        for _, key, text in keys:
            code = marshal.dumps(self.codes[text])
            index.extend([at + len(blob), len(key), at + len(blob) + len(key), len(code)])
            blob += key + code
        crcs = array("I", [crc for crc, _, _ in keys])
        if sys.byteorder == "big":
            index.byteswap()
            crcs.byteswap()
        return n.to_bytes(4, "little") + crcs.tobytes() + index.tobytes() + bytes(blob)


def record_package() -> tuple[Recorder, list[str]]:
    """Every module of the motorctl package imported under a :class:`Recorder`; with the
    modules that could not be imported (an optional library missing), each with why. Run in
    a fresh interpreter: a module imported before is not imported again."""
    import importlib
    import pkgutil

    import motorctl

    recorder, failed = Recorder(), []
    with recorder.use():
        for module in pkgutil.walk_packages(motorctl.__path__, "motorctl."):
            try:
                importlib.import_module(module.name)
            except ImportError as exc:
                failed.append(f"{module.name}: {exc}")
    return recorder, failed


def write(folder: Path) -> tuple[Path, Recorder, list[str]]:
    """:func:`record_package` written to ``folder`` (at build time: the build's own
    folder), as this interpreter's file; a file there before is replaced whole."""
    recorder, failed = record_package()
    payload = recorder.payload()
    path = folder / Path(str(default_path())).name
    temporary = path.with_name(f".{path.name}.new")
    temporary.write_bytes(header(payload) + payload)
    temporary.replace(path)
    return path, recorder, failed


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m motorctl.dataclass_code",
        description="Write the compiled code of every method @dataclass makes for motorctl's "
        "classes (at build time: setup.py, make).",
    )
    ap.add_argument("--write", metavar="FOLDER", type=Path, required=True)
    args = ap.parse_args(argv)
    if default_path() is None:
        print("this interpreter caches no bytecode: nothing written", file=sys.stderr)
        return 0
    path, recorder, failed = write(args.write)
    for line in failed:
        print(f"not imported (its methods are compiled at run time): {line}", file=sys.stderr)
    print(f"{path}: {len(recorder.codes)} methods")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
