"""How the reports word a figure, the same on every page: partial success with its count,
diagnostics keys as people read them (the labels live beside the keys, in mhrc.analysis.diagnostics),
and any value as HTML text."""

from __future__ import annotations

from html import escape
from typing import Any

from mhrc.analysis.diagnostics import label as diagnostic_label

__all__ = ["diagnostic_label", "html_text", "partial_success"]


def partial_success(ps: Any, placed: Any = None, total: Any = None) -> str:
    """`0.33 (1/3 placed)`, as the console prints it (mhrc.run.console); `0.33` when the counts are
    unknown, `unknown` when the score is."""
    try:
        value = float(ps)
    except (TypeError, ValueError):
        return "unknown"
    if isinstance(placed, int) and isinstance(total, int) and not isinstance(placed, bool):
        return f"{value:.2f} ({placed}/{total} placed)"
    return f"{value:.2f}"


def html_text(value: Any) -> str:
    """`value` as text inside HTML (an element or a quoted attribute); None as nothing."""
    return escape("" if value is None else str(value), quote=True)
