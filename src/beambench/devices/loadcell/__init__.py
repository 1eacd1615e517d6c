"""The load-cell plate: the MCU's wire codec (``protocol``) and the serial stream driver (``driver``)."""
