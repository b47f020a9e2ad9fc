"""The compiled dataclass methods made at build time (motorctl/dataclass_code.py).

A class defined under a file's :meth:`CodeCache.use` gets exactly the methods it gets
without it (the same code objects, the same behaviour), takes them from the file (none
compiled), and leaves ``dataclasses`` as it was; a file that is absent, stale (another
interpreter's bytecode or -O level), damaged, of another format, or not a regular file is
not used, says why, and every method is compiled as without it. The package's own file, as
``make`` and ``setup.py`` write it, holds every method a serving start imports (the real
daemon's and its executor's starts: tests/daemon/start/test_launch_startup.py and
tests/motion/executors/process/test_child_imports.py).
"""

from __future__ import annotations

import dataclasses
import marshal
import os
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from motorctl import dataclass_code
from motorctl.dataclass_code import CodeCache, Recorder, header
from tests.support import REPO

#: the package's methods a file holds at least: Python 3.11 and 3.12 compile each method
#: alone (some 900 texts), 3.13 all of a class's together (one text a class, some 170)
AT_LEAST = 300 if sys.version_info < (3, 13) else 100


def define() -> dict[str, type]:
    """Dataclasses of every kind motorctl declares: frozen with equality and hashing,
    ordered, with defaults and factories, a field named ``self``, plain."""

    @dataclasses.dataclass(frozen=True)
    class Point:
        """A frozen record."""

        x: int
        y: int = 0
        tags: tuple[str, ...] = dataclasses.field(default_factory=tuple)

    @dataclasses.dataclass(order=True)
    class Step:
        """An ordered, mutable record."""

        at: float
        self: str = "me"

    @dataclasses.dataclass(frozen=True, eq=False)
    class Handle:
        """Frozen, compared by identity."""

        name: str

    return {"Point": Point, "Step": Step, "Handle": Handle}


def behaviour(classes: dict[str, type]) -> list[Any]:
    """What the classes do, as values to compare between two definitions."""
    point: Any = classes["Point"]
    step: Any = classes["Step"]
    handle: Any = classes["Handle"]
    p = point(1, tags=("a",))
    done: list[Any] = [repr(p), p == point(1, 0, ("a",)), hash(p) == hash(point(1, 0, ("a",)))]
    done += [dataclasses.asdict(p), repr(dataclasses.replace(p, y=5))]
    done += [[f.name for f in dataclasses.fields(point)], vars(point)["__init__"].__qualname__]
    attempts: list[Callable[[], None]] = [lambda: setattr(p, "x", 2), lambda: delattr(p, "y")]
    for attempt in attempts:
        with pytest.raises(dataclasses.FrozenInstanceError) as raised:
            attempt()
        done.append(str(raised.value))
    done += [step(1.0) < step(2.0), repr(step(3.0, "you")), step(1.0) == step(1.0)]
    done += [handle("a") == handle("a"), repr(handle("a"))]
    return done


def methods(classes: dict[str, type]) -> dict[str, Any]:
    """Every generated method's code, by class and name."""
    return {
        f"{name}.{attr}": getattr(cls, attr).__code__
        for name, cls in classes.items()
        for attr in ("__init__", "__repr__", "__eq__", "__lt__", "__setattr__", "__delattr__")
        if hasattr(getattr(cls, attr, None), "__code__")
        and getattr(cls, attr).__qualname__.startswith(cls.__qualname__)
    }


@pytest.fixture
def built(tmp_path: Path) -> Path:
    """A file recorded from :func:`define`, as the build writes one."""
    recorder = Recorder()
    with recorder.use():
        define()
    payload = recorder.payload()
    path = tmp_path / "dataclass_code.bin"
    path.write_bytes(header(payload) + payload)
    return path


def test_a_class_gets_the_recorded_code_and_behaves_the_same(built: Path) -> None:
    plain = define()
    codes = CodeCache.load(built)
    assert codes.problem is None and len(codes) > 0
    with codes.use():
        cached = define()
    assert codes.misses == 0 and codes.hits == len(codes)  # every method from the file
    assert "from" in codes.summary() and "0 compiled" in codes.summary()
    assert methods(cached) == methods(plain)  # code objects equal: the same code
    assert len(methods(plain)) >= 8  # read as meant
    assert behaviour(cached) == behaviour(plain)
    assert "exec" not in vars(dataclasses)  # as it was


def test_a_released_table_is_not_used_again(built: Path) -> None:
    codes = CodeCache.load(built)
    with codes.use():
        define()
    hits = codes.hits
    codes.release()
    assert len(codes) == 0 and codes.problem is None
    with codes.use():
        classes = define()
    assert codes.hits == hits and codes.misses == hits  # compiled, as without the file
    assert behaviour(classes) == behaviour(define())


def test_a_text_not_in_the_file_is_compiled(built: Path) -> None:
    codes = CodeCache.load(built)
    with codes.use():

        @dataclasses.dataclass(frozen=True)
        class Other:
            """Not recorded."""

            unheard_of: int

    assert Other(1) == Other(1) and repr(Other(2)).endswith("<locals>.Other(unheard_of=2)")
    # each method (3.11, 3.12) or the class's methods together (3.13) compiled, none found
    assert codes.misses >= (4 if sys.version_info < (3, 13) else 1) and codes.hits == 0


def unusable(path: Path, codes: CodeCache, says: str) -> None:
    """``codes`` is not used, says ``says``, and a class is compiled as without it."""
    assert codes.problem is not None and says in codes.problem, codes.problem
    assert str(path) in codes.problem and "not used" in codes.summary()
    assert not codes.failed_in_use  # found when loaded (daemon/start/main.py warns)
    assert len(codes) == 0
    with codes.use():
        classes = define()
    assert codes.hits == 0 and codes.misses > 0
    assert methods(classes) == methods(define())
    assert behaviour(classes) == behaviour(define())


def test_an_absent_file_is_not_used(tmp_path: Path) -> None:
    path = tmp_path / "none.bin"
    unusable(path, CodeCache.load(path), "absent")


def test_a_file_of_another_interpreter_is_stale(built: Path) -> None:
    data = bytearray(built.read_bytes())
    at = len(dataclass_code.FORMAT)  # the bytecode's magic number: 3.11's minus one
    data[at : at + 2] = (int.from_bytes(data[at : at + 2], "little") - 1).to_bytes(2, "little")
    built.write_bytes(bytes(data))
    unusable(built, CodeCache.load(built), "stale")


def test_a_file_for_another_optimisation_level_is_stale(built: Path) -> None:
    data = bytearray(built.read_bytes())
    data[len(dataclass_code.FORMAT) + 4] ^= 1  # the -O level
    built.write_bytes(bytes(data))
    unusable(built, CodeCache.load(built), "stale")


@pytest.mark.parametrize("where", [-1, -400, 32])
def test_a_damaged_file_is_corrupt(built: Path, where: int) -> None:
    data = bytearray(built.read_bytes())
    data[where] ^= 0x55  # in the payload, at its end, and in its CRC (bytes 31-34)
    built.write_bytes(bytes(data))
    unusable(built, CodeCache.load(built), "corrupt")


def test_a_cut_short_file_is_corrupt(built: Path) -> None:
    built.write_bytes(built.read_bytes()[:-100])
    unusable(built, CodeCache.load(built), "corrupt")


@pytest.mark.parametrize(
    ("payload", "says"),
    [
        ((1000).to_bytes(4, "little") + bytes(100), "does not fit"),
        ((2).to_bytes(4, "little") + (9).to_bytes(4, "little") + bytes(36), "not in order"),
        ((1).to_bytes(4, "little") + bytes(4) + (10**6).to_bytes(4, "little") * 4, "outside"),
    ],
)
def test_a_file_with_a_valid_crc_but_a_bad_index_is_corrupt(
    tmp_path: Path, payload: bytes, says: str
) -> None:
    path = tmp_path / "bad.bin"
    path.write_bytes(header(payload) + payload)
    unusable(path, CodeCache.load(path), says)


def test_a_method_whose_code_is_not_code_is_corrupt(tmp_path: Path) -> None:
    """A file whose CRC holds (written so) but whose one method's code is a marshalled
    string: found out when it is asked for, and the file not used from then on."""
    recorder = Recorder()
    with recorder.use():
        define()
    text = sorted(recorder.codes)[0]
    recorder.codes = {text: recorder.codes[text]}
    payload = bytearray(recorder.payload())
    code = marshal.dumps(recorder.codes[text])
    at = payload.index(code)
    payload[at : at + len(code)] = marshal.dumps("x" * (len(code) - 5))
    path = tmp_path / "strange.bin"
    path.write_bytes(header(payload) + payload)
    codes = CodeCache.load(path)
    assert codes.problem is None and len(codes) == 1
    assert codes.code(text) is None
    assert codes.problem is not None and "corrupt: a method's code" in codes.problem
    assert codes.failed_in_use
    assert len(codes) == 0 and codes.misses == 1


@pytest.mark.parametrize("data", [b"\x7fELF" + bytes(100), b"", dataclass_code.FORMAT])
def test_a_file_of_another_format_or_empty_is_corrupt(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "other.bin"
    path.write_bytes(data)
    unusable(path, CodeCache.load(path), "corrupt")


def test_a_fifo_is_not_waited_on(tmp_path: Path) -> None:
    path = tmp_path / "fifo.bin"
    os.mkfifo(path)
    found: list[CodeCache] = []
    reader = threading.Thread(target=lambda: found.append(CodeCache.load(path)), daemon=True)
    reader.start()
    reader.join(10)
    assert not reader.is_alive(), "CodeCache.load waited on a FIFO"
    unusable(path, found[0], "cannot be read")


def test_the_hook_is_gone_after_the_block_however_it_ends(built: Path) -> None:
    codes = CodeCache.load(built)
    with pytest.raises(KeyError), codes.use():
        assert "exec" in vars(dataclasses)
        raise KeyError("out")
    assert "exec" not in vars(dataclasses)


def test_a_second_block_at_the_same_time_is_refused(built: Path) -> None:
    codes = CodeCache.load(built)
    with codes.use():
        with pytest.raises(RuntimeError, match="taken already"), codes.use():
            pass
        assert "exec" in vars(dataclasses)  # the first block's, untouched
    assert "exec" not in vars(dataclasses)


def test_the_built_file_holds_every_method_of_the_package(tmp_path: Path) -> None:
    """python -m motorctl.dataclass_code --write (setup.py's build_py, make) in a fresh
    interpreter: a file this interpreter uses, with no module left out here (the dev
    install has every optional library)."""
    run = subprocess.run(
        [sys.executable, "-m", "motorctl.dataclass_code", "--write", str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
        check=True,
    )
    assert run.stderr == ""  # every module imported
    written = tmp_path / Path(str(dataclass_code.default_path())).name
    assert run.stdout.startswith(f"{written}: ")
    codes = CodeCache.load(written)
    assert codes.problem is None and len(codes) > AT_LEAST
    assert not list(tmp_path.glob(".*.new"))  # written whole, under its name


def test_the_checkouts_file_is_the_one_the_build_writes(tmp_path: Path) -> None:
    """motorctl/dataclass_code.<tag>.bin (make writes it; make test runs this) is what the
    package's modules give now: not stale (run ``make dataclass-code`` after editing)."""
    installed = dataclass_code.default_path()
    assert installed is not None and installed.parent == REPO / "motorctl"
    subprocess.run(
        [sys.executable, "-m", "motorctl.dataclass_code", "--write", str(tmp_path)],
        capture_output=True,
        cwd=REPO,
        timeout=120,
        check=True,
    )
    fresh = CodeCache.load(tmp_path / installed.name)
    assert CodeCache.load(installed).methods() == fresh.methods(), "stale: make dataclass-code"
    assert len(fresh) > AT_LEAST  # read as meant
