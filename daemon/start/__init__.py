"""The start-up chain: from the ``motorctld`` command line to a running daemon, and its exit.

In order: launch.py (the ``motorctld`` command: the step executor's interpreter started
early), main.py (the command line, and the commands that print and exit, with the platform
check of ``--probe``: platform_check.py, platform_kernel.py), serve.py (runs a daemon until a
stop signal, signals.py, and shuts it down), assemble.py (builds everything it runs, with
the link's optional parts of link_parts.py), and timeline.py (when each step of the start
ended). Each imports only those after it; nothing of the daemon outside this package imports
any of it (tests/test_imports.py): the jobs beside it (config/, dispatcher.py, link/,
state/, status/, service.py, refusals.py, instance.py, errors.py) are built and run here,
they do not build or run one another.

No state of its own; each module says which thread owns what.
"""
