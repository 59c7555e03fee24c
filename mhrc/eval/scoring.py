"""One finished episode as the driver scores it: its trace read once, its metrics
(`mhrc.analysis.metrics`) and failure diagnostics (`mhrc.analysis.diagnostics`, given those metrics) computed once, and its
HTML report drawn from the same lines and the same diagnostics."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mhrc.analysis.diagnostics import Diagnostics, diagnose
from mhrc.analysis.metrics import EpisodeMetrics, from_trace
from mhrc.core.logs import get_logger
from mhrc.core.records import TraceLine, read_records

log = get_logger("mhrc.eval")


def read_episode_trace(path: Path) -> list[TraceLine]:
    """The lines of an episode's trace, decoded once (mhrc.core.records): the one place the
    evaluation reads a trace. Raises OSError or ValueError (records.TraceLineError)."""
    return read_records(path)


@dataclass(frozen=True)
class Scored:
    """An episode's trace lines with what the evaluation computes from them, once each."""

    path: Path
    lines: list[TraceLine]
    metrics: EpisodeMetrics
    diagnostics: Diagnostics


def score(path: Path) -> Scored:
    """Read the trace at `path` and score it. Raises OSError or ValueError (mhrc.analysis.metrics.TraceError
    for a trace without what the metrics need)."""
    lines = read_episode_trace(path)
    metrics = from_trace(lines)
    return Scored(path=path, lines=lines, metrics=metrics, diagnostics=diagnose(lines, metrics))


def write_episode_report(scored: Scored) -> None:
    """The episode's HTML report beside its trace (summary.html links it), from the lines and the
    diagnostics already in hand; a report that cannot be drawn costs a warning, never the row."""
    from mhrc.viewer.load import from_records
    from mhrc.viewer.show import default_out, render_report

    try:
        render_report(from_records(scored.path, scored.lines), default_out(scored.path), scored.diagnostics)
    except Exception as exc:
        log.warning("episode report not written", trace=str(scored.path), error=f"{type(exc).__name__}: {exc}")
