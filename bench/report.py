"""Shared by the benchmarks: percentiles and writing the JSON report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def percentile(xs: list[float], q: float) -> float:
    """The q-quantile (0..1) of xs, nearest rank below."""
    xs = sorted(xs)
    return xs[int(q * (len(xs) - 1))]


def int_range(text: str) -> list[int]:
    """The integers a --seeds style argument names: "0-9", "3,4,5", "0-2,7"."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def emit(report: dict[str, Any], out: Path | None) -> None:
    """Print the report as JSON and, with --out, write it to that file too."""
    text = json.dumps(report, indent=2)
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
    print(text)
