"""The files `mhrc eval` and `mhrc report` write beside the rows: summary.md, summary.csv and
summary.html."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mhrc.eval.html import write_html_summary
from mhrc.eval.report import summary_csv, summary_markdown


SUMMARY_FILES = ("summary.md", "summary.csv", "summary.html")  # what write_summaries writes, in the order people read them


def write_summaries(rows: list[dict[str, Any]], out: Path) -> None:
    """SUMMARY_FILES in `out`: summary.md, summary.csv and summary.html (tables and plots, `mhrc.eval.html`)."""
    if not rows:
        return
    md, csv, html = (out / name for name in SUMMARY_FILES)
    csv.write_text(summary_csv(rows), encoding="utf-8")
    md.write_text(summary_markdown(rows), encoding="utf-8")
    write_html_summary(rows, html)
