"""A recording from a trace: `mhrc show TRACE --rerun` and `mhrc eval --rerun DIR`.

The trace is read as the HTML report reads it (mhrc.viewer.load): a truncated trace, or one of an
older protocol version, gives a recording of what could be read, with the same warnings.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from mhrc.core.protocol import EpisodeStarted
from mhrc.viewer.load import LoadedTrace, load_trace
from mhrc.viewer.rerun import Mode, Target
from mhrc.viewer.rerun.episode import EpisodeLogger
from mhrc.viewer.rerun.sinks import Viewer, close_stream, open_stream, start_viewer


@dataclass(frozen=True)
class Written:
    """A recording made from a trace: where it went, the records fed, the warnings about the trace, and the
    viewer mhrc started for it (serve, spawn: still up, `Viewer.stop` ends it)."""

    target: Target
    records: int
    warnings: list[str]
    viewer: Viewer | None = None


def log_trace(trace: LoadedTrace, rec: rr.RecordingStream) -> list[str]:
    """Feed every record of `trace` into `rec`, then its blueprint; returns the warnings (the trace's and the drawing's)."""
    logger = EpisodeLogger(rec)
    for line in trace.records:
        logger.feed(line)
    logger.finish()
    return list(trace.warnings) + logger.warnings


def write_recording(path: str | Path, target: Target, recording_id: str | None = None) -> Written:
    """Read the trace at `path` (a file or a run directory) and send it to `target`. Raises
    mhrc.viewer.load.NotATrace for a file that is no trace, OSError for one that cannot be read,
    RuntimeError for a viewer that does not start."""
    trace = load_trace(path)
    viewer = start_viewer(target)
    rec = open_stream(recording_id or _run_of(trace), target.path, viewer.url if viewer is not None else None)
    try:
        warnings = log_trace(trace, rec)
    finally:
        close_stream(rec)
    return Written(target, len(trace.records), warnings, viewer)


def rrd_beside(trace: Path, directory: Path, root: Path) -> Target:
    """The .rrd of `trace` in `directory`, at the trace's place under `root` (its run's folder), named for it."""
    try:
        rel = trace.relative_to(root)
    except ValueError:
        rel = Path(trace.name)
    return Target(Mode.FILE, (directory / rel).with_suffix(".rrd"))


def _run_of(trace: LoadedTrace) -> str:
    started = trace.first(EpisodeStarted)
    return started.run if started is not None and started.run else trace.path.stem
