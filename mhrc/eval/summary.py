"""The statistics of a set of evaluation rows, computed once: `Summary` holds, per setting and
task, the valid rows, their means with 95% bootstrap intervals, their failure diagnostics and the
paper's figures where the configuration matches. summary.md, summary.csv and summary.html are
renderings of one Summary (mhrc.eval.report, mhrc.eval.html); none computes a statistic again."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from mhrc.eval.means import summarize_diagnostics
from mhrc.eval.pairs import PairedArms, paired_comparisons
from mhrc.eval.paper import PaperMatch, Ran, paper_match
from mhrc.eval.records import EvalRow
from mhrc.eval.rows import (
    CI_SEED,
    RESAMPLES,
    SETTING,
    Setting,
    by_setting_task,
    cell_stats,
    is_valid,
    order_key,
    setting_defaults,
    setting_of,
)

Cell = tuple[Setting, str]  # (setting, task)


def ran(row: EvalRow) -> Ran:
    """What the paper's figures read of a row."""
    s, m = row.settings, row.metrics
    return Ran(s.method, tuple(m.robots), m.scene, m.n_objects, s.prompts, s.base_url)


def matches_of(cells: dict[Cell, list[EvalRow]]) -> dict[Cell, PaperMatch]:
    """`paper_match` of every (setting, task) cell, the setting given by its field names."""
    defaults = setting_defaults()  # a row that records no field: every field's default
    return {k: paper_match(dict(zip(SETTING, k[0])), k[1], [ran(r) for r in v], defaults) for k, v in cells.items()}


@dataclass(frozen=True)
class Summary:
    """Every statistic the summaries show of `rows` (of one or several evaluations)."""

    rows: list[EvalRow]
    valid: list[EvalRow]
    resamples: int
    seed: int
    cells: dict[Cell, list[EvalRow]]  # the valid rows by setting and task, in the order every table lists them
    stats: dict[Cell, dict[str, Any]]  # means and intervals (mhrc.eval.rows.cell_stats)
    diagnostics: dict[Cell, dict[str, Any]]  # mhrc.eval.means.summarize_diagnostics
    matches: dict[Cell, PaperMatch]  # the paper's figures, or why not
    invalid: Counter[Cell]  # invalid rows left out, by setting and task
    links: list[str | None]  # links[i]: the link to rows[i]'s episode report (None: none)
    paired: PairedArms  # every two arms compared on the episodes they share (mhrc.eval.pairs)

    @classmethod
    def of(
        cls,
        rows: list[EvalRow],
        *,
        resamples: int = RESAMPLES,
        seed: int = CI_SEED,
        links: Sequence[str | None] | None = None,
        compare: tuple[Setting, Setting] | None = None,
    ) -> Summary:
        """The statistics of `rows`; `links[i]`, the link to rows[i]'s report, is kept with its row;
        `compare`: the two arms the paired comparison is restricted to (default: every two)."""
        if links is not None and len(links) != len(rows):
            raise ValueError(f"{len(links)} links for {len(rows)} rows")
        # in key order, not the order workers finished in: the bootstrap resamples by position, so the same
        # rows give the same intervals however the episodes were scheduled; each link moves with its row
        paired = sorted(
            zip(rows, links if links is not None else [None] * len(rows)),
            key=lambda p: (p[0].key, p[0].repeat),
        )
        rows = [r for r, _ in paired]
        valid = [r for r in rows if is_valid(r)]
        cells = by_setting_task(valid)
        return cls(
            rows=rows,
            valid=valid,
            resamples=resamples,
            seed=seed,
            cells=cells,
            stats={k: cell_stats(v, resamples=resamples, seed=seed) for k, v in cells.items()},
            diagnostics={k: summarize_diagnostics([r.diagnostics for r in v]) for k, v in cells.items()},
            matches=matches_of(cells),
            invalid=Counter((setting_of(r), r.metrics.task) for r in rows if not is_valid(r)),
            links=[link for _, link in paired],
            paired=paired_comparisons(valid, only=compare, resamples=resamples, seed=seed),
        )

    @property
    def tasks(self) -> list[str]:
        return sorted({r.metrics.task for r in self.valid})

    @property
    def settings(self) -> list[Setting]:
        """The valid rows' settings, in the order every table lists them."""
        return sorted({setting for setting, _ in self.cells}, key=order_key)
