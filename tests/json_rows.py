"""Hand-built trace lines: JSON rows as a trace file holds them, decoded as mhrc.core.records reads a
file's lines (older shapes upgraded by mhrc.core.upgrade), for tests that build a trace by hand."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from mhrc.core.records import TraceLine, decode_row


def records(rows: Iterable[Mapping[str, Any]]) -> list[TraceLine]:
    """Each row decoded into a TraceLine, numbered from 1 as a file's lines are."""
    return [decode_row(row, n) for n, row in enumerate(rows, 1)]
