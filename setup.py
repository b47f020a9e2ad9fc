"""The compiled step core, the one C extension of motorctl (everything else: pyproject.toml).

``motorctl.motion.executors._stepcore`` from motion/executors/csrc/
(motion/executors/compiled_core.py loads and drives it). Built by the package's own build,
never at run time: ``make venv`` (pip's editable install builds it in place, beside the
executors' modules), ``make stepcore`` after a change to
its sources, the wheel and the Debian package (dh-python, python3-all-dev). Warnings are
errors. ``CFLAGS``/``LDFLAGS`` from the environment are added (``make test-asan`` builds it
with the address and undefined-behaviour sanitizers).
"""

from setuptools import Extension, setup

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
    ext_modules=[
        Extension(
            "motorctl.motion.executors._stepcore",
            sources=[f"motion/executors/csrc/{name}" for name in SOURCES],
            depends=[f"motion/executors/csrc/{name}" for name in ("stepcore.h", "module.h")],
            extra_compile_args=["-std=gnu11", "-Wall", "-Wextra", "-Werror", "-O2"],
        )
    ]
)
