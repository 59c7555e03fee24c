"""Paired comparisons in the summaries: every two arms (settings, as mhrc.eval.rows.setting_of and
setting_label define them) that ran some of the same episodes are compared episode by episode
(mhrc.eval.paired: the mean paired difference in TS and AS with its paired-bootstrap 95% interval,
the exact McNemar test on success and its discordant counts).

An episode is its task, scene, object count and seed: not its key, which carries a team prefix
for a team other than the paper's, so that two teams (or two methods, protocols, models) on one
grid pair up. Only valid rows enter (an invalid row is left out of every table); an episode one
arm ran and the other did not is left out and listed. Arms that share no episode are skipped,
in one line each. `mhrc report --compare A B` restricts the comparison to two arms, named by
their setting label or a unique substring of it (`resolve_arm`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

from mhrc.eval.paired import Outcome, Paired, compare
from mhrc.eval.records import EvalRow
from mhrc.eval.rows import Setting, order_key, setting_label, setting_of
from mhrc.run.config import ConfigError

__all__ = ["PairedArms", "arms_of", "episode_of", "paired_comparisons", "paired_markdown", "resolve_arm"]


def episode_of(row: EvalRow) -> str:
    """The episode a row ran, whichever arm ran it: task/scene/objects/seed (no team prefix)."""
    m = row.metrics
    return f"{m.task}/{m.scene}/{m.n_objects}/{m.seed}"


def outcome_of(row: EvalRow) -> Outcome:
    """A row's figures for the comparison: success, TS, and AS as the tables read it (the steps with
    a non-wait action of any robot; NaN for a row written before that reading)."""
    m = row.metrics
    return Outcome(m.success, float(m.temporal_steps), float("nan") if m.active_ticks is None else m.active_ticks)


def arms_of(valid: Sequence[EvalRow]) -> dict[Setting, dict[str, Outcome]]:
    """Each arm's outcomes by episode, the arms in the order every table lists them; of an episode
    an arm ran twice (merged runs of one setting), the first row in key order."""
    arms: dict[Setting, dict[str, Outcome]] = {}
    for r in sorted(valid, key=lambda r: (r.key, r.repeat)):
        arms.setdefault(setting_of(r), {}).setdefault(episode_of(r), outcome_of(r))
    return dict(sorted(arms.items(), key=lambda kv: order_key(kv[0])))


@dataclass(frozen=True)
class PairedArms:
    """The paired comparisons of a summary: each pair of arms that share an episode, and the pairs
    skipped because they share none (as (label a, label b))."""

    compared: list[Paired]
    skipped: list[tuple[str, str]]


def paired_comparisons(
    valid: Sequence[EvalRow], *, only: tuple[Setting, Setting] | None = None, resamples: int, seed: int
) -> PairedArms:
    """Every pair of arms of `valid` (or only the pair `only`), arm a before arm b in table order."""
    arms = arms_of(valid)
    if only is not None:
        pairs = [only]
    else:
        pairs = list(combinations(arms, 2))
    compared, skipped = [], []
    for a, b in pairs:
        label_a, label_b = setting_label(a), setting_label(b)
        p = compare(label_a, label_b, arms.get(a, {}), arms.get(b, {}), resamples=resamples, seed=seed)
        if p.n:
            compared.append(p)
        else:
            skipped.append((label_a, label_b))
    return PairedArms(compared, skipped)


def resolve_arm(name: str, settings: Sequence[Setting]) -> Setting:
    """The arm `name` names: the setting whose label is `name`, else the one whose label holds it;
    ConfigError (one line listing the labels) when none or several do."""
    labels = {setting_label(s): s for s in settings}
    if name in labels:
        return labels[name]
    found = [label for label in labels if name in label]
    if len(found) == 1:
        return labels[found[0]]
    known = "; ".join(sorted(labels)) or "none"
    if not found:
        raise ConfigError(f"--compare: no arm is named {name!r} (arms: {known})")
    raise ConfigError(
        f"--compare: {name!r} names {len(found)} arms ({'; '.join(sorted(found))}); give more of the label"
    )


PAIRED_NOTE = (
    "Every two arms that ran some of the same episodes (the same task, scene, object count and seed), compared "
    "episode by episode over the valid episodes both ran: the mean difference A - B in TS and in AS (negative: A "
    "took fewer steps) with a 95% paired-bootstrap interval ({resamples} resamples of the paired episodes, seed "
    "{seed}), and the exact McNemar test on success (a two-sided binomial test on the episodes one arm solved and "
    "the other did not). Episodes only one arm ran are left out, and listed below the table."
)


def _diff(value: float | None, ci: tuple[float, float] | None) -> str:
    if value is None or ci is None or value != value:  # NaN: a row written before AS was recorded
        return "-"
    return f"{value:+.2f} [{ci[0]:+.2f}, {ci[1]:+.2f}]"


def paired_markdown(paired: PairedArms, *, resamples: int, seed: int) -> list[str]:
    """The "Paired comparisons" section of summary.md, or nothing when no two arms were compared."""
    if not paired.compared and not paired.skipped:
        return []
    lines = ["## Paired comparisons", "", PAIRED_NOTE.format(resamples=resamples, seed=seed), ""]
    if paired.compared:
        head = (
            "| A | B | paired episodes | left out (only A / only B) | TS A - B [95% CI] | AS A - B [95% CI] | "
            "solved by A only | solved by B only | McNemar p |"
        )
        lines += [head, "| --- |" + " --- |" * (head.count("|") - 2)]
        for p in paired.compared:
            lines.append(
                f"| {p.a} | {p.b} | {p.n} | {len(p.only_a)} / {len(p.only_b)} | {_diff(p.ts_diff, p.ts_ci)} | "
                f"{_diff(p.as_diff, p.as_ci)} | {p.a_only_solved} | {p.b_only_solved} | {p.mcnemar_p:.4f} |"
            )
        lines.append("")
        for p in paired.compared:
            left = [f"{e} (only A)" for e in p.only_a] + [f"{e} (only B)" for e in p.only_b]
            lines.append(
                f"- {p.a} vs {p.b}: paired {', '.join(p.episodes)}; left out: {', '.join(left) if left else 'none'}"
            )
        lines.append("")
    for a, b in paired.skipped:
        lines.append(f"Skipped {a} vs {b}: no episode in common.")
    return lines + ([""] if paired.skipped else [])
