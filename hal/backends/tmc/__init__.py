"""The SPI driver layer ("spidev"): Trinamic TMC2130 and TMC5160 driver chips over
/dev/spidevB.C, attached to the motors of whichever backend built the machine."""
