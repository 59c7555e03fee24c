"""Shared by the benchmarks: percentiles, writing the JSON report, and the trees a benchmark compares."""

from __future__ import annotations

import json
import os
import subprocess
import sys
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


def commit_of(root: Path) -> str:
    """The short commit of the checkout at `root`, " (dirty)" when it has changes; "unknown" outside git."""
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain"], capture_output=True, text=True).stdout
    return head + (" (dirty)" if dirty.strip() else "")


def check_tree(root: Path, module: str = "mhrc.world.sim", who: str = "") -> None:
    """A child with PYTHONPATH set to `root` imports that tree's mhrc, not the installed one (SystemExit if not)."""
    got = subprocess.run(
        [sys.executable, "-c", f"import {module} as m; print(m.__file__)"],
        env={**os.environ, "PYTHONPATH": str(root)},
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    if not Path(got).resolve().is_relative_to(root.resolve()):
        raise SystemExit(f"{who + ': ' if who else ''}mhrc imports from {got}, not from {root}")
