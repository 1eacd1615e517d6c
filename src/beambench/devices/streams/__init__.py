"""The streams of the hardware and emulated rigs, one module each, registered on import (``@device_stream(name)``,
:mod:`beambench.devices.streams.registry`): each builds its driver from its rig-file section and names its emulated
peer (the other end of its wire protocol, on this machine). Adding a device stream: a new module here and its name
in this import list (docs/extending.md); the list's order is the rig's."""

# isort: off  (the import order is the streams' order in a rig)
from beambench.devices.streams import (  # noqa: F401, I001  (each module registers its stream on import)
    mocap,
    loadcells,
)

# isort: on
from beambench.devices.streams.registry import DEVICE_STREAMS, DeviceContext, device_stream

__all__ = ["DEVICE_STREAMS", "DeviceContext", "device_stream"]
