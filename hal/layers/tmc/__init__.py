"""The TMC layer: Trinamic TMC2130 and TMC5160 driver chips over /dev/spidevB.C (py-spidev),
attached to the motors of whichever backend built the machine (``[motors.tmc]``,
``[spidev]``).

- ``config.py``: its declaration: ``[motors.tmc]`` and ``[spidev]``, the chips by name, a
  motor's driver spec;
- ``layer.py``: what the registry calls (attach the drivers, probe them);
- ``fields.py``: what the chips share (bit fields keyed by their register, what a chip is,
  the registers and fields both have); as Klipper's tmc*.py, one module per chip holding
  its whole driver: ``tmc2130.py`` (its registers, fields and current scaling),
  ``tmc5160.py`` (the same, and :class:`~motorctl.hal.layers.tmc.tmc5160.Tmc5160`: the
  driver of its own ramp generator, the HAL's RampDriver);
- ``driver.py``: the driver both chips share (start-up, DRV_STATUS read by the HAL's driver
  poller, ``--probe``'s reading), ``settings.py``: a driver's settings and register values,
  ``link.py``: the chips' 40-bit datagrams over the HAL's SPI bus (hal/spi.py).
"""
