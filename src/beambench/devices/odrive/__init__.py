"""ODrive v3.6: the CAN Simple codec (``cansimple``); the Motor driver over CAN (``can_motor``, composing the bus
link ``can_link``, the axis as heard ``can_axis`` and its supervision ``can_watch``) and over USB (``usb_motor``);
what both drivers share: the limits they send (``limits``), the telemetry stream (``telemetry``), the host-stall
check (``host_stall``)."""
