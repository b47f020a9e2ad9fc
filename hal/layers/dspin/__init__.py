"""The dSPIN layer: ST's L6470, L6472, L6480 and powerSTEP01 (voltage and current mode),
daisy-chained on one SPI chip select, running their own motion profiles.

So far its pure parts (no I/O, no clock, no state: any thread), built on the datasheet
tables of :mod:`motorctl.hal.dspin`:

- ``chain.py``: the daisy chain's framing: a command for chip k of N as the sequence of
  N-byte transfers (one byte per chip per transfer, NOP for the chips not addressed), and
  chip k's answer picked out of what came back;
- ``convert.py``: the protocol's units (step/s, step/s^2, positions in microsteps) to the
  chip's registers, with each register's resolution and range and the rule for what the
  chip cannot take (clamp and count, or refuse as E1);
- ``program.py``: what each protocol motion command becomes on the chip.

The layer's declaration, its attachment to the shared SPI bus and the HAL's driver poller
come with the integration (docs/dspin.md, "What is built and what is next").
"""
