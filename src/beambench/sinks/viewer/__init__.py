"""The Rerun live view of a run or a saved session: layout per rig (``layout``), the 3-D scene (``scene``), the
step panel (``step``), the viewer process (``spawn``) and the sink that logs batches (``sink``).

The Rerun modes are declared here, not in ``sink``, so the CLI can offer them without importing rerun.
"""

from typing import Literal

RerunMode = Literal["spawn", "connect", "save", "off"]
