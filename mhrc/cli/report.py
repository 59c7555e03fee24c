"""`mhrc report`: one or several `mhrc eval` directories merged into one comparison."""

from __future__ import annotations

from pathlib import Path

import click

from mhrc.core.writable import unwritable
from mhrc.run.errors import ConfigError


@click.command("report")
@click.argument("dirs", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    metavar="FILE.md",
    help="Write the markdown to FILE.md instead of stdout, FILE.csv and FILE.html beside it; the files written are named on stderr.",
)
@click.option(
    "--resamples",
    default=2000,
    show_default=True,
    type=click.IntRange(min=1),
    help="Bootstrap resamples per 95% confidence interval.",
)
@click.option(
    "--seed",
    default=0,
    show_default=True,
    type=int,
    help="Seed of the bootstrap (the same rows and seed give the same intervals).",
)
@click.option(
    "--compare",
    nargs=2,
    default=None,
    metavar="A B",
    help="Restrict the paired comparison to two arms, each named by its setting label (as the summary titles it) "
    "or a unique part of it; default: every two arms that share episodes.",
)
def report(
    dirs: tuple[Path, ...], out: Path | None, resamples: int, seed: int, compare: tuple[str, str] | None
) -> None:
    """Merge `mhrc eval` directories into one comparison (markdown on stdout): Succ, PS, TS
    and AS per task with 95% bootstrap confidence intervals, grouped by method, ablation and
    fidelity, and the paper's Table I / II figures beside the settings that match its
    configuration. Invalid episodes (model unreachable throughout) are left out and listed.
    With --out FILE.md, the markdown goes there instead, with FILE.csv and FILE.html (tables,
    plots, a link to each episode's report) beside it. Every two arms (settings) that ran some of
    the same episodes are compared episode by episode: the paired difference in TS and AS with a
    paired-bootstrap 95% interval and the exact McNemar test on success (--compare A B: only those two)."""
    from mhrc.eval.html import links_of
    from mhrc.eval.pairs import resolve_arm
    from mhrc.eval.records import read_dir
    from mhrc.eval.report import markdown
    from mhrc.eval.rows import is_valid, setting_of
    from mhrc.eval.summaries import write_summary_files
    from mhrc.eval.summary import Summary

    if out is not None:
        files = [out, out.with_suffix(".csv"), out.with_suffix(".html")]
        if len(set(files)) < len(files):
            raise click.BadParameter(
                f"{out} would be overwritten by the CSV or HTML beside it; name a .md file", param_hint="--out"
            )
        for f in files:
            if why := unwritable(f):
                raise click.BadParameter(why, param_hint="--out")
    try:
        per_dir = [(d, read_dir(d)) for d in dirs]  # each row validated, and of its directory's grid
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    rows = [r for _, mine in per_dir for r in mine]
    if not rows:
        raise click.UsageError("no finished episodes in " + ", ".join(map(str, dirs)))
    arms = None
    if compare is not None:
        settings = list(dict.fromkeys(setting_of(r) for r in rows if is_valid(r)))
        try:
            arms = (resolve_arm(compare[0], settings), resolve_arm(compare[1], settings))
        except ConfigError as exc:
            raise click.UsageError(str(exc)) from None
        if arms[0] == arms[1]:
            raise click.UsageError(f"--compare: {compare[0]!r} and {compare[1]!r} name the same arm")
    page_dir = (out or Path(".")).parent
    links = [link for d, mine in per_dir for link in links_of(mine, d, page_dir)]
    # every statistic, once, for the three files; each row's link sorted with it
    summary = Summary.of(rows, resamples=resamples, seed=seed, links=links, compare=arms)
    if out is None:
        click.echo(markdown(summary))
        return
    md, csv, html = files
    md.parent.mkdir(parents=True, exist_ok=True)  # checked creatable above (unwritable)
    try:
        write_summary_files(summary, md, csv, html, summary.links)
    except ConfigError as exc:
        raise click.BadParameter(str(exc), param_hint="--out") from None
    click.echo(f"wrote {md}, {csv}, {html}", err=True)
