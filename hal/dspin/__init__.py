"""The ST dSPIN family as its datasheets define it: L6470, L6472, L6480 and powerSTEP01 (in
voltage and in current mode). Pure data and functions, no I/O, no clock, no state: any
thread.

Two parts of motorctl speak dSPIN and neither may import the other (tests/test_imports.py:
no backend or layer imports another): the dSPIN layer (``hal/layers/dspin/``: the host's
side, framing a daisy chain and converting the protocol's units) and the mock backend's
chip model (``hal/backends/mock/dspin_chip.py``: the chip's side, decoding the byte stream
and running the motion profile). What both must agree on, because the datasheets say it
once, is declared once here:

- ``registers.py``: every register of each model (address, length in bits, reset value,
  when it may be written, its bit fields), keyed by name as Klipper's TMC field tables are;
- ``status.py``: the STATUS register of each model, bit by bit, decoded into named flags;
- ``chips.py``: the chips themselves (:class:`~motorctl.hal.dspin.chips.Chip`: a model in a
  mode, its registers, its STATUS, its ALARM_EN bits, its microstep limit);
- ``commands.py``: the command set and its byte encoding, both ways;
- ``scales.py``: what one LSB of each speed and acceleration register is, from the
  250 ns tick.

docs/dspin.md says where each fact comes from (the datasheet section or table, and the
public implementations that were read to check it).
"""
