"""What a status reader gets of the link: :meth:`Link.status
<motorctl.daemon.link.loop.Link.status>`, built here.

Threads: called on the status thread (or any reader's) while the link thread serves. It only
copies: counters whose keys all exist from the start (one C-level dict copy each under the
GIL), the processing time's and the CPU count's totals, and the session's last frames,
described on the reader's thread (:meth:`LinkSession.describe_recent
<motorctl.daemon.link.session.LinkSession.describe_recent>`). Nothing of the link is changed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from motorctl.daemon.link.loop import Link


def report(link: Link, unsent_bytes: int) -> dict[str, object]:
    """The link's state for ``motorctld --status`` (daemon/status/document.py);
    ``unsent_bytes``: its answers' bytes not yet written."""
    session = link.session
    counts: dict[str, object] = dict(session.counters)
    counts.update(link.counters)
    counts.update(link.watch.counters)
    peer = "open"
    if link.peer_gone:
        away = link.away
        peer = "closed" if away is None else "gone" if away.ever_open else "waiting"
    out: dict[str, object] = {
        "counters": counts,
        "processing": link.processing.summary(),
        "held": session.held,
        "waiting": session.waiting,
        "peer": peer,
        "unsent_bytes": unsent_bytes,
        "recent": session.describe_recent(),
    }
    if link.device is not None:
        out["device"] = link.device.path
    if link.parts is not None:
        out["cpu_parts"] = link.parts.summary()
    return out
