"""Whether a file or directory could be written, asked before a run starts (nothing imported but
the standard library: `mhrc eval`'s and `mhrc report`'s modules check it before the bus is loaded)."""

from __future__ import annotations

import os
from pathlib import Path


def unwritable(path: Path, *, directory: bool = False) -> str | None:
    """Why `path` (a file, or with `directory` a directory) could not be created and written,
    or None. Creates nothing: checked before a run starts, a bad `--trace` or `--out` costs one
    line instead of a traceback from a half-started run."""
    if path.exists():
        if directory and not path.is_dir():
            return f"{path} is not a directory"
        if not directory and path.is_dir():
            return f"{path} is a directory, not a file"
        if not os.access(path, os.W_OK | (os.X_OK if directory else 0)):
            return f"{path} is not writable"
        return None
    parent = next(p for p in path.parents if p.exists())  # the root always exists
    if not parent.is_dir():
        return f"cannot create {path}: {parent} is not a directory"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"cannot create {path}: {parent} is not writable"
    return None
