"""ABS_POS, the dSPIN chips' position counter: its width (the register's length in
``registers.py``) and what follows from it. Its own module, light, because the config's
declaration (``hal/layers/dspin/config.py``) and the driver spec (``spec.py``) check
against it without importing the register tables (a start whose config names no dSPIN
motor imports none of them: tests/daemon/start/test_launch_startup.py).

Constants: any thread.
"""

from __future__ import annotations

from typing import Final

#: ABS_POS (and MARK): microsteps, two's complement
ABS_POS_BITS: Final = 22
ABS_POS_MIN: Final = -(1 << (ABS_POS_BITS - 1))
ABS_POS_MAX: Final = (1 << (ABS_POS_BITS - 1)) - 1
#: how many microsteps the counter holds before it wraps round
ABS_POS_SPAN: Final = 1 << ABS_POS_BITS
