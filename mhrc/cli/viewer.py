"""`mhrc scenes`, `mhrc render` (the scenes) and `mhrc show` (an episode's report or video)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from mhrc.cli.options import VIDEO_HELP, VIDEO_SIZE, rerun_option


@click.command()
def scenes() -> None:
    """List the scene layouts (world/scenes/*.json; `--scene FILE.json` loads your own)."""
    from mhrc.world.layouts import LAYOUTS

    for layout in LAYOUTS.values():
        names = ", ".join(
            f"{f.name} ({f.kind})" if f.kind != f.name.split("_")[0] else f.name for f in layout.furniture
        )
        click.echo(f"{layout.name}: {layout.description}\n  furniture: {names}\n  file: {layout.source}")


@click.command()
@click.option(
    "--scene",
    "scenes_",
    multiple=True,
    help="Scene layout or layout .json file (repeatable; default: every built-in layout).",
)
@click.option("--task", default="pack_objects", show_default=True, help="Task whose fixtures and objects are shown.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode whose objects are shown.")
@click.option("--objects", "n_objects", default=6, show_default=True, type=int)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("renders"), show_default=True)
def render(scenes_: tuple[str, ...], task: str, seed: int, n_objects: int, out: Path) -> None:
    """Write top-down and perspective PNGs of each scene (CPU renderer, no display needed):
    OUT/<scene>_top.png and OUT/<scene>_perspective.png."""
    from mhrc.world.checks import check_episode
    from mhrc.world.layouts import LAYOUTS
    from mhrc.world.render import render_scene

    try:
        for scene in scenes_ or tuple(LAYOUTS):
            check_episode(task=task, scene=scene, n_objects=n_objects)
        for scene in scenes_ or tuple(LAYOUTS):
            for path in render_scene(scene, out, seed=seed, n_objects=n_objects, task=task):
                click.echo(str(path))
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None


@click.command()
@click.argument("run_or_trace", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="The HTML file to write; default: beside the trace, with .html (with --video: only when --out is given).",
)
@click.option("--video", type=click.Path(dir_okay=False, path_type=Path), default=None, help=VIDEO_HELP)
@rerun_option(help="Make the episode's Rerun recording (pip install 'mhrc[rerun]'): OUT.rrd, or `serve`, `spawn`.")
@VIDEO_SIZE
def show(run_or_trace: Path, out: Path | None, video: Path | None, rerun: Any, video_size: tuple[int, int]) -> None:
    """Write one self-contained HTML report of an episode (map, robot lanes, messages, failures)
    from RUN_OR_TRACE: a trace file, or a run directory holding trace.jsonl. Prints its path.
    With --video, render the episode's video instead, with --rerun its Rerun recording (or as well, with --out)."""
    from mhrc.viewer.load import NotATrace
    from mhrc.viewer.show import write_report

    if (video is None and rerun is None) or out is not None:
        try:
            path, warnings = write_report(run_or_trace, out)
        except NotATrace as exc:
            click.echo(f"mhrc show: {exc}", err=True)
            sys.exit(2)
        except OSError as exc:
            click.echo(f"mhrc show: cannot read or write: {exc}", err=True)
            sys.exit(1)
        if warnings:
            click.echo("mhrc show: warning: " + "; ".join(warnings), err=True)
        click.echo(str(path))
    if video is not None:
        trace = run_or_trace / "trace.jsonl" if run_or_trace.is_dir() else run_or_trace
        click.echo(str(render_video_to(trace, video, video_size)))
    if rerun is not None:
        from mhrc.cli.rerun_view import show_rerun

        show_rerun(run_or_trace, rerun)


def render_video_to(trace: Path, video: Path, size: tuple[int, int] = (640, 480)) -> Path:
    """Render `trace` to `video` with a progress bar; one clear line and exit 2 on a bad input."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from mhrc.viewer.video import render_video

    with Progress(
        TextColumn("video"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), console=Console(stderr=True)
    ) as bar:
        task = bar.add_task("frames", total=None)
        try:
            info = render_video(
                trace,
                video,
                width=size[0],
                height=size[1],
                progress=lambda done, total: bar.update(task, completed=done, total=total),
            )
        except (ValueError, OSError) as exc:  # VideoError is a ValueError
            bar.stop()
            click.echo(f"mhrc show: {exc}", err=True)
            sys.exit(2)
    click.echo(f"{info.frames} frames in {info.render_seconds:.1f} s ({info.bytes / 1e6:.2f} MB)", err=True)
    return info.path
