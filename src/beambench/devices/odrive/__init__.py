"""ODrive v3.6: the CAN Simple codec (``cansimple``) and the Motor drivers over CAN (``can_motor``) and USB
(``usb_motor``)."""
