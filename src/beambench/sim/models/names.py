"""The grammar of beam model names, without MuJoCo: input checks (``sim.model``, ``--dry-run``) read it before any
model is built."""

from __future__ import annotations

import re

ROD_NAME = re.compile(r"rod(\d+)(g?)(s?)")
"""A segmented rod: ``rod<N>`` with ``g`` (Gauss–Legendre hinge spacing) and ``s`` (a strip) suffixes."""
