"""Names a file system and a reader can take: the scene's ``name`` and the output folders.

A name becomes a folder (``results/<name>/``) that a reader finds and types
again, so a character a reader cannot see or a terminal cannot show is
refused with the reason: control characters (newline, tab, ...), format
characters that take no space (zero-width space U+200B, joiners, direction
marks, soft hyphen), line and paragraph separators, private-use and
unassigned code points, and undecodable bytes (a command-line argument that
is not UTF-8 arrives as a lone surrogate, e.g. ``\\udcff`` for the byte 0xff).
"""

from __future__ import annotations

import unicodedata

REFUSED = {"Cc": "a control character (newline, tab, ...)", "Cf": "an invisible character",
           "Cs": "an undecodable byte (not UTF-8)", "Co": "a private-use character",
           "Cn": "an unassigned character", "Zl": "a line separator", "Zp": "a paragraph separator"}


def unreadable(text: str) -> str:
    """Why ``text`` is no name a reader can take (the first offending character), or ``""``."""
    for c in text:
        kind = unicodedata.category(c)
        if kind in REFUSED:
            if kind == "Cs" and 0xDC80 <= ord(c) <= 0xDCFF:
                shown = f"the byte 0x{ord(c) - 0xDC00:02x}"
            else:
                shown = f"U+{ord(c):04X}" + (f" {unicodedata.name(c)}" if unicodedata.name(c, "") else "")
            return f"{REFUSED[kind]}, {shown}"
    return ""

