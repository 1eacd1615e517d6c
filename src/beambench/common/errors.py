"""The root of every error beambench raises on purpose: catch :class:`BeambenchError` for "a clear message"."""

from __future__ import annotations


class BeambenchError(Exception):
    """An expected failure with a message fit for the user (bad input, a device fault, a failed fit)."""
