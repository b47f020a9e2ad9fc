"""The step executor's interpreter imports the fewest modules (motion/executors/process/
child.py): what its bootstrap imports before the daemon hands it its parameters (the child's
module, then every config section's module, ``config_sections``) is the step core, the
shared block, the hardware's declarations and the real-time set-up, and nothing of the
daemon, the client, the protocol, the planning side of motion, or the standard library's
process, command-line, config-file and archive modules. A fresh interpreter, as the
executor's is. Its dataclasses' methods come from the build's file
(motorctl/dataclass_code.py): none is compiled."""

from __future__ import annotations

import json
import os
import pickle
import socket
import subprocess
import sys

from motorctl.motion.executors.process.start import BOOTSTRAP, import_path, package_location
from tests.support import REPO

#: what the executor's interpreter never imports before its parameters come (a prefix ends
#: in "."); the compiled core's loader comes after them, when the parameters ask for it
NEVER = (
    "motorctl.daemon.",
    "motorctl.client.",
    "motorctl.protocol.",
    "motorctl.motion.engine",
    "motorctl.motion.motor",
    "motorctl.motion.dc",
    "motorctl.motion.executors.planner",
    "motorctl.motion.executors.thread",
    "motorctl.motion.executors.split",
    "motorctl.motion.executors.chip_ramp",
    "motorctl.motion.executors.compiled_core",
    "subprocess",
    "argparse",
    "tomllib",
    "tempfile",
    "shutil",
    "hashlib",
    "platform",
    "ctypes.util",
    "asyncio",
    "email",
    "http",
    "rich",
    "prometheus_client",
)

PROGRAM = """\
import json, sys
before = set(sys.modules)
from motorctl.motion.executors.process import child
child.config_sections()  # what child_main imports while it waits
print(json.dumps(sorted(set(sys.modules) - before)))
"""


def imported_by_the_executor() -> list[str]:
    out = subprocess.run(
        [sys.executable, "-c", PROGRAM], capture_output=True, text=True, cwd=REPO, check=True
    )
    names: list[str] = json.loads(out.stdout)
    return names


def never(name: str) -> bool:
    return any(
        name.startswith(n) if n.endswith(".") else name == n or name.startswith(n + ".")
        for n in NEVER
    )


def test_the_executor_imports_only_what_the_step_core_needs() -> None:
    names = imported_by_the_executor()
    assert "motorctl.motion.executors.step_core" in names  # what it is there for
    assert "motorctl.hal.shm" in names
    assert [n for n in names if never(n)] == []


#: run before the bootstrap in the executor's interpreter (tests/support/executors.py): at the
#: first collection (child_main's, once it has imported the config sections' modules, right
#: before it waits for its parameters), how many dataclass methods were created and how many
#: of them compiled, on stdout
COUNT_COMPILED = """\
import gc, sys
created, compiled = [], []
def audit(event, args):
    if event == "compile" and str(args[1]) == "<string>":
        source = args[0]
        text = source.decode() if isinstance(source, bytes) else str(source)
        if text.startswith("def __create_fn__("):
            compiled.append(1)
    elif event == "exec" and any(
        getattr(c, "co_name", "") == "__create_fn__" for c in args[0].co_consts
    ):
        created.append(1)
sys.addaudithook(audit)
def collected(phase, info):
    if phase == "stop" and not done:
        done.append(1)
        print(len(created), len(compiled), flush=True)
done = []
gc.callbacks.append(collected)
"""


def test_the_executor_imports_with_the_builds_compiled_dataclass_methods() -> None:
    """Its bootstrap (process/start.py) imports the step core's modules, and child_main the
    config sections', with motorctl/dataclass_code.py's file: no method compiled."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    proc = subprocess.Popen(
        [sys.executable, "-I", "-c", COUNT_COMPILED + BOOTSTRAP],
        stdin=theirs.fileno(),
        stdout=subprocess.PIPE,
        text=True,
    )
    theirs.close()
    try:
        ours.send(pickle.dumps((os.getpid(), import_path(), package_location())))
        assert proc.stdout is not None
        created, compiled = map(int, proc.stdout.readline().split())  # before it waits
    finally:
        ours.close()  # dismissed: it ends quietly
        assert proc.wait(30) == 0
    assert created > 50  # the step core's records, the config sections' (read as meant)
    assert compiled == 0, f"{compiled} of {created} compiled: run make dataclass-code"
