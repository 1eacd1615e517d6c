"""Type aliases shared by the packages."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

Floats: TypeAlias = Sequence[float] | np.ndarray
"""Numbers given as a list, a tuple or a 1-D array (vectors, quaternions, frequency lists)."""
