"""The SPI driver layer ("spidev"): Trinamic TMC2130 and TMC5160 driver chips over
/dev/spidevB.C, attached to the motors of whichever backend built the machine.

- ``config.py``: ``[motors.tmc]`` and ``[spidev]``, and a motor's driver spec;
- ``backend.py``: what the registry calls (attach the drivers, probe them);
- ``fields.py``: bit fields, what a chip is, the registers and fields both chips have;
  ``tmc2130.py``, ``tmc5160.py``: each chip's own registers, fields and constants, as data;
- ``settings.py``: a driver's settings, its currents and register values;
- ``spi.py``: the SPI bus (py-spidev), ``link.py``: the chips' 40-bit datagrams;
- ``driver.py``: a chip as a stepper driver (start-up, DRV_STATUS), ``ramp.py``: a TMC5160
  that runs its own ramp (the HAL's RampDriver), ``monitor.py``: the thread that polls them.
"""
