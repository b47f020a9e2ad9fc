"""The device side: motorctld, in wings by job (README.md, "Architecture").

At the top, what builds and runs the daemon: launch.py (the motorctld command), main.py (its
command line), serve.py (runs a daemon), assemble.py (builds everything it runs). Beside
them the parts they build: config/, dispatcher.py, service.py (systemd), instance.py,
signals.py, platform_check.py, errors.py; and the wings: link/ (the serial line), state/
(what is kept on disk, and how any file is written), status/ (the status document and its
readers). Each module says at its top which thread or process owns its state.
"""
