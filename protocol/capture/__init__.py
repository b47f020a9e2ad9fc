"""The trace file format (docs/trace.md): pcapng, interfaces of link type LINKTYPE_USER0.

Why it lives in protocol/: the daemon writes it (``motorctld --trace``), the client side
writes and reads it (``motorctl tap``, ``motorctl trace``, ``motorctl replay``), and
``client -> protocol <- daemon`` is the one room both may import. It is a pure codec like
the rest of the room: bytes in, bytes out, no file, no clock, no thread. Callers read and
write the files and pass the timestamps (and a session's name) in.

- format.py: the format's block and option codes, what a file carries (``CaptureInfo``:
  the settings a reader needs; ``Record``: one byte run; ``Direction``) and ``CaptureError``;
- writer.py: the header and the records' blocks as the recorders write them;
- reader.py: the one reader (pcapng and classic pcap, every kind of damage named by its
  offset); trace and replay both read through its ``parse``.

What a file holds:

- A Section Header Block whose comment carries the settings a reader needs to frame and
  decode the bytes again: ``motorctl-trace/1 role=daemon checksum=crc8 crc_covers_ack=0
  strict_padding=1 frame_gap_ms=10 session=3f2a9c01d4e5 part=1``, plus the recording
  program and the port. ``session`` names one recording (a daemon's run, a tap's run) and
  ``part`` numbers its files from 1 (the daemon's trace rotates), so a missing part and a
  missing start are noticed.
- One Interface Description Block: link type 147 (LINKTYPE_USER0, the range pcap leaves to
  private use), no snap length, timestamps in nanoseconds (``if_tsresol`` = 9), and the same
  settings comment again as its own ``opt_comment``: mergecap keeps only the first file's
  section comment, each interface keeps its own.
- One Enhanced Packet Block per byte run, as it was read from or written to the port, with
  its direction in ``epb_flags`` (bits 0-1): inbound (1) = host -> device, a command's bytes;
  outbound (2) = device -> host, an answer's bytes. Directions are always named from the
  device's side, in the daemon's trace and in the tap's alike. ``epb_dropcount`` says how
  many byte runs a writer that fell behind left out just before this one.

Timestamps: nanoseconds, ``origin_wall_ns + (t - origin_t)``, where ``t`` is the recorder's
monotonic clock: differences between records are differences of the monotonic clock (no NTP
step can make them jump), and the absolute values read as wall-clock time in Wireshark.

Nothing is imported here: each module is imported by its own name.
"""
