"""The tests mirror the package: each test file is named after the module it tests.

``tests/<room>/<folders>/test_<name>.py`` tests a module (or package) of
``<room>/<folders>/``: ``<name>`` is the module's name, or starts with it and an underscore
and says which part of it the file holds (``test_server_subscribe.py``: the status
server's subscriptions; ``test_serve_e2e.py``: daemon/serve.py, against motorctld as a
process on a real PTY). So a newcomer finds a module's tests by its path, and a test file's
module by its name (tests/conftest.py).
"""

from __future__ import annotations

from pathlib import Path

from tests.support import REPO

ROOMS = ("protocol", "client", "daemon", "motion", "hal")
#: Rooms whose tests do not mirror the room yet, with the reason; a room here that mirrors
#: it is taken off (the last test below fails until it is).
NOT_YET = {
    "hal": "tests/hal/ is flat while hal/backends/ is nested (issue 23's hal part moves it)",
}


def module_of(test_file: Path) -> Path | None:
    """The module (or package) a test file is named after, None when there is none."""
    rel = test_file.relative_to(REPO / "tests")
    folder = REPO.joinpath(*rel.parts[:-1])
    parts = test_file.stem.removeprefix("test_").split("_")
    for i in range(len(parts), 0, -1):  # the longest name first: session_end before session
        name = "_".join(parts[:i])
        for candidate in (folder / f"{name}.py", folder / name / "__init__.py"):
            if candidate.exists():
                return candidate
    return None


def unnamed(room: str) -> list[str]:
    """The test files of ``room`` named after no module of it."""
    files = sorted((REPO / "tests" / room).rglob("test_*.py"))
    return [str(f.relative_to(REPO)) for f in files if module_of(f) is None]


def test_each_test_file_is_named_after_the_module_it_tests() -> None:
    found = {room: unnamed(room) for room in ROOMS if room not in NOT_YET}
    assert sum(len(list((REPO / "tests" / r).rglob("test_*.py"))) for r in found) > 40
    assert {room: files for room, files in found.items() if files} == {}


def test_a_test_file_is_matched_with_its_module() -> None:
    daemon = REPO / "tests" / "daemon"
    assert module_of(daemon / "link" / "test_session_end.py") == (
        REPO / "daemon" / "link" / "session_end.py"
    )
    assert module_of(daemon / "status" / "test_server_subscribe.py") == (
        REPO / "daemon" / "status" / "server.py"
    )
    assert module_of(daemon / "test_config.py") == REPO / "daemon" / "config" / "__init__.py"
    assert module_of(daemon / "test_e2e.py") is None  # names no module: not allowed
    assert module_of(daemon / "link" / "test_assemble.py") is None  # not in daemon/link/


def test_the_rooms_not_mirrored_yet_are_still_not() -> None:
    """A room that mirrors the package now is taken off ``NOT_YET``, not kept for later."""
    for room in NOT_YET:
        assert unnamed(room), f"tests/{room}/ mirrors {room}/ now: take it off NOT_YET"
