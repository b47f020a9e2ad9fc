"""The compiled step core, the one C extension of motorctl, and the compiled code of the
dataclasses' methods (everything else: pyproject.toml).

``motorctl.motion.executors._stepcore`` from motion/executors/csrc/
(motion/executors/compiled_core.py loads and drives it). Built by the package's own build,
never at run time: ``make venv`` (pip's editable install builds it in place, beside the
executors' modules), ``make stepcore`` after a change to
its sources, the wheel and the Debian package (dh-python, python3-all-dev). Warnings are
errors. ``CFLAGS``/``LDFLAGS`` from the environment are added (``make test-asan`` builds it
with the address and undefined-behaviour sanitizers).

The dataclasses' methods: ``build_py`` (:class:`BuildPy`), once it has copied the modules,
writes ``motorctl/dataclass_code.<cache tag>.bin`` beside them, the code the building
interpreter compiles for every method ``@dataclass`` adds to motorctl's classes
(motorctl/dataclass_code.py: a start uses it instead of compiling them again). So the wheel
and the Debian package hold it for the interpreter they are built for, as the step core; the
editable install (``make venv``) writes it in place, and ``make`` again after a change to the
modules. A module that cannot be imported at build time (a library missing) is named on
stderr; its classes' methods are compiled at run time, as without the file.

And the licence, MIT, the one part of the metadata pyproject.toml cannot declare for every
setuptools the project builds with: ``license = "MIT"`` there (an SPDX expression, PEP 639)
needs setuptools >= 77, and Debian 12's is 66 (make deb and make test-root SUITE=bookworm build
with it), which refuses that form and knows only the table ``license = { text = "MIT" }``,
which setuptools >= 77 deprecates (setuptools 84: builds that use it "will no longer be
supported" after 2027-02-18). So
pyproject.toml names ``license`` dynamic and it is given here, as the SPDX expression
(``License-Expression: MIT``) to a setuptools that knows them, as the older ``License: MIT``
field to one that does not. Either way the LICENSE file goes with it (setuptools' default
license-files patterns). tests/packaging/test_debian.py checks both with the setuptools at
hand and Debian's.
"""

import os
import subprocess
import sys
from pathlib import Path

import setuptools
from setuptools import Extension, setup
from setuptools.command.build_py import build_py

LICENSE = "MIT"
#: the first setuptools that takes an SPDX expression (``license_expression``, PEP 639)
EXPRESSIONS_FROM = 77


def license_metadata() -> dict[str, str]:
    """The licence, in the form the setuptools at hand reads."""
    if int(setuptools.__version__.split(".")[0]) >= EXPRESSIONS_FROM:
        return {"license_expression": LICENSE}
    return {"license": LICENSE}


class BuildPy(build_py):
    """build_py, then the dataclasses' compiled methods beside the built modules (in place
    for an editable install): ``python -m motorctl.dataclass_code --write``, run by the
    building interpreter on the modules it has just built."""

    def run(self) -> None:
        super().run()
        editable = getattr(self, "editable_mode", False)
        tree = Path(__file__).resolve().parent if editable else Path(self.build_lib).resolve()
        subprocess.run(
            [sys.executable, "-m", "motorctl.dataclass_code", "--write", str(tree / "motorctl")],
            cwd=tree,
            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},  # no __pycache__ in a wheel
            check=True,
        )


SOURCES = [
    "core.c",
    "drive.c",
    "rings.c",
    "lines_gpio.c",
    "lines_sim.c",
    "module.c",
    "module_lines.c",
]

setup(
    **license_metadata(),
    cmdclass={"build_py": BuildPy},
    ext_modules=[
        Extension(
            "motorctl.motion.executors._stepcore",
            sources=[f"motion/executors/csrc/{name}" for name in SOURCES],
            depends=[f"motion/executors/csrc/{name}" for name in ("stepcore.h", "module.h")],
            extra_compile_args=["-std=gnu11", "-Wall", "-Wextra", "-Werror", "-O2"],
        )
    ],
)
