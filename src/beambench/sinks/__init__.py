"""Where batches go: the HDF5 session file (``hdf5``) and the Rerun live view (``rerun_view``).

The Rerun modes are declared here, not in ``rerun_view``, so the CLI can offer them without importing rerun.
"""

from typing import Literal, get_args

RerunMode = Literal["spawn", "connect", "save", "off"]
RERUN_MODES: tuple[str, ...] = get_args(RerunMode)
