"""Shared by the benchmarks: percentiles and writing the JSON report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def percentile(xs: list[float], q: float) -> float:
    """The q-quantile (0..1) of xs, nearest rank below."""
    xs = sorted(xs)
    return xs[int(q * (len(xs) - 1))]


def emit(report: dict[str, Any], out: Path | None) -> None:
    """Print the report as JSON and, with --out, write it to that file too."""
    text = json.dumps(report, indent=2)
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
    print(text)
