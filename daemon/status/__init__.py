"""The status wing: the status document and everything that serves or shows it.

- document.py: the status document, built in this one module (docs/status.md), and
  systemd's one-line STATUS= summary of it;
- server.py: the status socket's server (one document, or a subscription);
- reader.py: the socket's clients (``motorctld --status``, the monitor, benchmarks, tests);
- metrics.py: the document as metrics (``--status --format ...``);
- monitor.py, monitor_view.py: the live monitor (``motorctl monitor``, ``--status --watch``),
  the view drawn with monitor_layout.py (styled lines, tables), monitor_parts.py (each part
  of a document) and monitor_screen.py (the terminal); only the view's modules import rich.

The top wing: it reads the link and the state wing, and neither of them imports it
(tests/test_imports.py). Each module says which thread owns what.
"""
