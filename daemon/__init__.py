"""The device side: motorctld, in wings by job (README.md, "Architecture").

In its root, the jobs: config/, dispatcher.py, refusals.py (the error answers' reasons),
service.py (systemd), instance.py (one daemon per state directory and PTY) and errors.py
(the start-up error the link's ports raise too); the wings: link/ (the serial line), state/
(what is kept on disk, and how any file is written), status/ (the status document and its
readers). Above them, start/: what builds and runs the daemon (launch.py, the motorctld
command; main.py, its command line; serve.py, runs a daemon; assemble.py, builds everything
it runs), which none of the jobs imports. Each module says at its top which thread or
process owns its state.
"""
