"""Text a device sent, made safe to print: no terminal control sequences, no control characters.

A NatNet server names itself in SERVERINFO, an ODrive reports its firmware, a load-cell MCU its identity: bytes
from the network or a serial port. Printed raw, an escape sequence in them can retitle the terminal window, write
the clipboard (OSC 52), hide text or move the cursor. :func:`printable` removes ANSI/VT escape sequences (CSI, OSC,
DCS…, 7-bit and 8-bit forms), then every other control character (C0, DEL, C1) and the bidirectional overrides
(text that displays reversed); what is left is one line. Use it wherever device text reaches the terminal.
"""

from __future__ import annotations

import re
import unicodedata

__all__ = ["printable"]

# ESC-introduced sequences: CSI (ESC [ … final byte), OSC/DCS/SOS/PM/APC (ESC ] P X ^ _ … up to BEL or ST), and
# two-byte escapes (ESC + one character); 8-bit forms: CSI 0x9b, OSC 0x9d, DCS 0x90, SOS 0x98, PM 0x9e, APC 0x9f
_SEQUENCES = re.compile(
    r"(?:\x1b\[|\x9b)[0-?]*[ -/]*[@-~]?"
    r"|(?:\x1b[\]PX^_]|[\x90\x98\x9d\x9e\x9f])[^\x07\x1b\x9c]*(?:\x07|\x1b\\|\x9c)?"
    r"|\x1b[\x20-\x7e]?"
)
_BIDI = frozenset("\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069\u200e\u200f\u061c")


def printable(text: object, limit: int | None = 200) -> str:
    """``text`` (any value, as ``str``) without escape sequences and control characters, on one line, cut to
    ``limit`` characters (None: whole)."""
    s = _SEQUENCES.sub("", str(text))
    s = "".join(
        " " if c in "\t\n\r" else c for c in s if c in "\t\n\r" or not (unicodedata.category(c) == "Cc" or c in _BIDI)
    )
    if limit is not None and len(s) > limit:
        s = s[: limit - 1] + "…"
    return s
