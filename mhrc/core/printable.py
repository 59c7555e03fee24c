"""Text a participant or a model wrote, made safe to print on an operator's terminal.

A message's content, an object's name, an agent id or a model's reply can hold control
characters: an ANSI escape recolours the terminal, sets its window title or clears the screen,
a bidi override reorders what the operator reads. `printable()` removes them (a line break or a
tab becomes a space, so one record stays one line); the console also escapes Rich markup on
top (mhrc.run.console), and every log line's texts go through it (mhrc.core.logs)."""

from __future__ import annotations

import unicodedata

_SPACES = str.maketrans({"\n": " ", "\r": " ", "\t": " ", "\v": " ", "\f": " "})


def printable(text: object) -> str:
    """`text` without control characters (C0, DEL, C1) or invisible format characters (bidi
    overrides, zero-width marks); line breaks and tabs become spaces."""
    s = str(text).translate(_SPACES)
    if s.isprintable():
        return s
    return "".join(c for c in s if c == " " or unicodedata.category(c) not in ("Cc", "Cf", "Cs", "Zl", "Zp"))
