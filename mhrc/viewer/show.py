"""`mhrc show`: a trace in, one self-contained HTML report out."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mhrc.analysis.diagnostics import Diagnostics, diagnose
from mhrc.core.records import TraceLine
from mhrc.viewer.load import LoadedTrace, load_trace, resolve
from mhrc.viewer.model import build_view
from mhrc.viewer.page import render_page


def diagnostics_for(lines: Sequence[TraceLine]) -> tuple[Diagnostics | None, str | None]:
    """mhrc.analysis.diagnostics' findings for the failure panel, or why there are none."""
    try:
        return diagnose(lines), None
    except Exception as exc:  # a diagnosis that fails must not cost the user the report
        return None, f"the failure diagnosis failed on this trace: {type(exc).__name__}: {exc}"


def default_out(path: str | Path) -> Path:
    """Beside the trace, with .html."""
    return resolve(path).with_suffix(".html")


def write_report(path: str | Path, out: str | Path | None = None) -> tuple[Path, list[str]]:
    """Render the trace at `path` (file or run directory) to `out`; returns it and the warnings.
    Raises load.NotATrace for a file that is no trace."""
    trace = load_trace(path)
    target = Path(out) if out is not None else default_out(path)
    return target, render_report(trace, target, *diagnostics_for(trace.records))


def render_report(trace: LoadedTrace, target: Path, diag: Diagnostics | None, note: str | None = None) -> list[str]:
    """Write the report of a trace already read, with its diagnostics already computed (`mhrc eval`
    has both); returns the warnings."""
    view = build_view(trace)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(render_page(view, diag, note), encoding="utf-8")
    return view.warnings
