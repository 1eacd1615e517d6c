"""The sim backend's streams, one module each, registered on import (``@sim_stream(name)``,
:mod:`beambench.backends.sim_streams.registry`). Adding a simulated stream: a new module here and its name in
this import list (docs/extending.md); the list's order is the session's."""

# isort: off  (the import order is the streams' order in a session)
from beambench.backends.sim_streams import (  # noqa: F401, I001  (each module registers its stream on import)
    mocap,
    loadcell,
)

# isort: on
from beambench.backends.sim_streams.registry import SIM_STREAMS, SimStreamContext, sim_stream

__all__ = ["SIM_STREAMS", "SimStreamContext", "sim_stream"]
