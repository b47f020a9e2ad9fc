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
(daemon/start/main.py); every method is then compiled, as without it.

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
import os
import stat
import sys
import zlib
from collections.abc import Callable, Iterator, Mapping
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


def header(payload: bytes) -> bytes:
    """The file's header for ``payload``, for this interpreter: the format, the bytecode's
    magic number, the optimisation level (``-O``), the payload's CRC-32."""
    return (
        FORMAT
        + importlib.util.MAGIC_NUMBER
        + bytes([sys.flags.optimize])
        + zlib.crc32(payload).to_bytes(4, "little")
    )


def default_path() -> Path | None:
    """Where this interpreter's file is, beside this module; None for an interpreter
    without a cache tag (it caches no bytecode either)."""
    tag = sys.implementation.cache_tag
    return None if tag is None else Path(__file__).with_name(f"{STEM}.{tag}.bin")


def compile_method(text: str) -> CodeType:
    """``text`` compiled as ``exec(text, ...)`` in ``dataclasses`` compiles it."""
    return compile(text, "<string>", "exec", dont_inherit=True)


class CodeCache:
    """The recorded code of one file, and what a start took from it."""

    def __init__(self, path: Path | None, codes: Mapping[str, bytes], problem: str | None):
        self.path = path
        self._codes = codes
        #: why the file is not used (absent, stale, corrupt); None when it is
        self.problem = problem
        #: the methods whose code came from the file, and those compiled (not in it)
        self.hits = 0
        self.misses = 0

    @classmethod
    def load(cls, path: Path | None = None) -> CodeCache:
        """The file at ``path`` (this interpreter's, :func:`default_path`, by default); one
        that cannot be used is empty, with its :attr:`problem`. Never raises for the file."""
        path = default_path() if path is None else path
        if path is None:
            return cls(None, {}, "this interpreter caches no bytecode (no cache tag)")
        try:
            data = read_regular(path)
        except FileNotFoundError:
            return cls(path, {}, f"{path} is absent (built by setup.py or make)")
        except OSError as exc:
            return cls(path, {}, f"{path} cannot be read: {exc.strerror or exc}")
        size = len(FORMAT) + len(importlib.util.MAGIC_NUMBER) + 5
        head, payload = data[:size], data[size:]
        if not head.startswith(FORMAT):
            return cls(path, {}, f"{path} is corrupt: not a {FORMAT.decode().strip()!r} file")
        if head[: size - 4] != header(payload)[: size - 4]:
            return cls(path, {}, f"{path} is stale: made by another interpreter or -O level")
        if head != header(payload):
            return cls(path, {}, f"{path} is corrupt: its CRC does not match its contents")
        try:
            codes = marshal.loads(payload)
        except (EOFError, ValueError, TypeError) as exc:
            return cls(path, {}, f"{path} is corrupt: {exc}")
        if not isinstance(codes, dict):
            return cls(path, {}, f"{path} is corrupt: it holds no table of methods")
        return cls(path, codes, None)

    def __len__(self) -> int:
        return len(self._codes)

    def code(self, text: str) -> CodeType | None:
        """The recorded code of ``text``, None when the file has none (counted either way)."""
        found = self._codes.get(text)
        if found is not None:
            code = marshal.loads(found)
            if isinstance(code, CodeType):
                self.hits += 1
                return code
        self.misses += 1
        return None

    def release(self) -> None:
        """The start's imports are done: let the table go (about a MiB, which the step
        executor would otherwise keep locked in memory); a later :meth:`use` compiles."""
        self._codes = {}

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


def read_regular(path: Path) -> bytes:
    """The contents of the regular file ``path``: OSError for anything else (a FIFO is not
    waited on) or one over :data:`MAX_BYTES`."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_BYTES:
            raise OSError(0, f"not a regular file of at most {MAX_BYTES} bytes")
        with os.fdopen(os.dup(fd), "rb") as f:
            return f.read(MAX_BYTES + 1)
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
        """What the file holds after its header (texts in order: the same build, the same
        bytes)."""
        return marshal.dumps({text: marshal.dumps(self.codes[text]) for text in sorted(self.codes)})


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
