"""`--rerun` of `mhrc up`, `mhrc show` and `mhrc eval`: the recording's start, its end and what is said
about it (mhrc.viewer.rerun does the recording). rerun-sdk is imported only here, inside the functions."""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:
    from mhrc.viewer.rerun import Target
    from mhrc.viewer.rerun.live import LiveRecording
    from mhrc.viewer.rerun.sinks import Viewer


def start_live(target: Target, run: str, command: str) -> LiveRecording:
    """The live recording of run `run`, its viewer started (serve, spawn); one line and exit 2 if it cannot start."""
    from mhrc.viewer.rerun.live import LiveRecording

    try:
        live = LiveRecording(target, run)
    except (RuntimeError, OSError) as exc:
        click.echo(f"mhrc {command}: --rerun {target.mode.value}: {exc}", err=True)
        sys.exit(2)
    if live.address is not None:
        click.echo(f"rerun: {live.address}", err=True)
    return live


def both(*hooks: Callable[[Any, str], None] | None) -> Callable[[Any, str], None] | None:
    """One observer hook calling each of `hooks` (None left out); None when there is none."""
    if not any(h is not None for h in hooks):
        return None

    def observe(bus: Any, run: str) -> None:
        for hook in hooks:
            if hook is not None:
                hook(bus, run)

    return observe


def close_live(live: LiveRecording, command: str) -> None:
    """Close the live recording and say where it is and what it holds."""
    stats = live.close()
    where = live.target.path or live.address
    said = f"rerun: {where} ({stats.logged} records"
    said += f", {stats.dropped} dropped)" if stats.dropped else ")"
    click.echo(said, err=True)
    for warning in stats.warnings:
        click.echo(f"mhrc {command}: rerun: warning: {warning}", err=True)


def keep_serving(viewer: Viewer | None) -> None:
    """A served recording stays up for the person looking at it until Ctrl-C (or SIGTERM); a file needs nothing."""
    if viewer is None:
        return
    stop = threading.Event()
    before = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    click.echo(f"rerun: serving {viewer.address} until Ctrl-C", err=True)
    try:
        while not stop.is_set() and viewer.process.poll() is None:
            stop.wait(0.5)
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        viewer.stop()


def show_rerun(trace: Path, target: Target) -> None:
    """`mhrc show TRACE --rerun`: the recording from the trace, with the warnings `mhrc show` gives."""
    from mhrc.viewer.load import NotATrace
    from mhrc.viewer.rerun.record import write_recording

    try:
        written = write_recording(trace, target)
    except NotATrace as exc:
        click.echo(f"mhrc show: {exc}", err=True)
        sys.exit(2)
    except (RuntimeError, OSError) as exc:
        click.echo(f"mhrc show: --rerun: {exc}", err=True)
        sys.exit(1)
    if written.warnings:
        click.echo("mhrc show: warning: " + "; ".join(written.warnings), err=True)
    click.echo(str(target.path) if written.viewer is None else f"rerun: {written.viewer.address}")
    keep_serving(written.viewer)


def eval_recordings(traces: Iterable[Path], directory: Path, root: Path) -> list[Path]:
    """`mhrc eval --rerun DIR`: one recording per episode's trace, at its place under `root` in DIR.
    A trace that cannot be read, or whose recording would land outside DIR (a path with ../), is said
    and skipped: the evaluation's results stand."""
    from mhrc.eval.directory import inside
    from mhrc.viewer.load import NotATrace
    from mhrc.viewer.rerun.record import rrd_beside, write_recording

    out = []
    for trace in traces:
        target = rrd_beside(trace, directory, root)
        assert target.path is not None
        if not (inside(trace, root) and inside(target.path, directory)):
            click.echo(f"mhrc eval: --rerun: {trace}: outside {root}; no recording written for it", err=True)
            continue
        try:
            write_recording(trace, target)
        except (NotATrace, OSError, RuntimeError) as exc:
            click.echo(f"mhrc eval: --rerun: {trace}: {exc}", err=True)
            continue
        assert target.path is not None
        out.append(target.path)
    return out
