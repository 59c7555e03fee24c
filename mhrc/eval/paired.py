"""Paired comparisons of two arms (two settings: protocols, teams, models) on the episodes they share.

Two arms run on the same episodes (the same task, scene, object count and seed) are compared
episode by episode, not interval beside interval: the per-episode differences in TS and AS get a
paired-bootstrap 95% interval of their mean (the episodes resampled with replacement, each
keeping both arms' figures), and success gets the exact McNemar test, a two-sided binomial test
on the discordant pairs (episodes one arm solved and the other did not), with p = 1/2, what
`scipy.stats.binomtest` computes. Episodes only one arm ran are left out and listed, never imputed.

The differences read `a - b`: a negative TS difference means arm `a` needed fewer steps."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from math import comb

from mhrc.eval.rows import CI_LEVEL, CI_SEED, bootstrap_ci
from mhrc.eval.rows import RESAMPLES as RESAMPLES

__all__ = ["Outcome", "Paired", "compare", "mcnemar_exact", "paired_bootstrap_ci"]

SEED = CI_SEED
LEVEL = CI_LEVEL


@dataclass(frozen=True)
class Outcome:
    """One arm's figures of one episode."""

    success: bool
    ts: float
    as_ticks: float


@dataclass(frozen=True)
class Paired:
    """Arm `a` against arm `b` over the episodes both ran (`episodes`, sorted)."""

    a: str
    b: str
    episodes: tuple[str, ...]
    only_a: tuple[str, ...]  # episodes arm a ran and b did not: left out
    only_b: tuple[str, ...]
    ts_diff: float | None  # mean of a - b over the paired episodes
    ts_ci: tuple[float, float] | None
    as_diff: float | None
    as_ci: tuple[float, float] | None
    a_only_solved: int  # discordant pairs: a solved, b did not
    b_only_solved: int
    mcnemar_p: float | None  # exact two-sided; None with no paired episode

    @property
    def n(self) -> int:
        return len(self.episodes)


def paired_bootstrap_ci(
    diffs: list[float], *, resamples: int = RESAMPLES, seed: int = SEED, level: float = LEVEL
) -> tuple[float, float]:
    """Percentile interval of the mean paired difference: the episodes (each one difference) are
    resampled with replacement, as every interval of the summaries is drawn (`rows.bootstrap_ci`)."""
    return bootstrap_ci(diffs, resamples=resamples, seed=seed, level=level)


def mcnemar_exact(a_only: int, b_only: int) -> float:
    """The exact McNemar test's two-sided p-value from the discordant pair counts (1.0 with none)."""
    if a_only < 0 or b_only < 0:
        raise ValueError("discordant counts are never negative")
    n = a_only + b_only
    # under the null each discordant pair falls either way with probability 1/2: the binomial
    # distribution is symmetric, so the two-sided p doubles the smaller tail (at most 1)
    tail = sum(comb(n, i) for i in range(min(a_only, b_only) + 1))
    return min(1.0, 2 * tail / 2**n)


def compare(
    a: str,
    b: str,
    arm_a: Mapping[str, Outcome],
    arm_b: Mapping[str, Outcome],
    *,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> Paired:
    """Arm `a` against arm `b`, each a map from an episode's identity to its outcome."""
    shared = tuple(sorted(set(arm_a) & set(arm_b)))
    only_a = tuple(sorted(set(arm_a) - set(arm_b)))
    only_b = tuple(sorted(set(arm_b) - set(arm_a)))
    if not shared:
        return Paired(a, b, shared, only_a, only_b, None, None, None, None, 0, 0, None)
    import numpy as np  # here: a refused `mhrc eval` command line, which imports this module, needs no numerics

    ts = [arm_a[e].ts - arm_b[e].ts for e in shared]
    steps = [arm_a[e].as_ticks - arm_b[e].as_ticks for e in shared]
    a_only = sum(1 for e in shared if arm_a[e].success and not arm_b[e].success)
    b_only = sum(1 for e in shared if arm_b[e].success and not arm_a[e].success)
    return Paired(
        a=a,
        b=b,
        episodes=shared,
        only_a=only_a,
        only_b=only_b,
        ts_diff=float(np.mean(ts)),
        ts_ci=paired_bootstrap_ci(ts, resamples=resamples, seed=seed),
        as_diff=float(np.mean(steps)),
        as_ci=paired_bootstrap_ci(steps, resamples=resamples, seed=seed),
        a_only_solved=a_only,
        b_only_solved=b_only,
        mcnemar_p=mcnemar_exact(a_only, b_only),
    )
