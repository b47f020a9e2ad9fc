"""The step executor's interpreter imports the fewest modules (motion/executors/process/
child.py): what its bootstrap imports before the daemon hands it its parameters (the child's
module, then every config section's module, ``config_sections``) is the step core, the
shared block, the hardware's declarations and the real-time set-up, and nothing of the
daemon, the client, the protocol, the planning side of motion, or the standard library's
process, command-line, config-file and archive modules. A fresh interpreter, as the
executor's is."""

from __future__ import annotations

import json
import subprocess
import sys

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
