"""`mhrc report` compares arms paired on the episodes they share (issue 45, item 5): on small
hand-made evaluation directories the rendered figures equal a hand computation, episodes one arm
ran alone are left out and listed, arms with no episode in common are skipped in one line, and
`--compare A B` names two arms by label (an unknown or ambiguous one is one line, exit 2)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.eval.records import EvalManifest
from mhrc.eval.spec import EvalSpec

GRID = {"tasks": ("pack_objects",), "scenes": ("kitchen",), "objects": (3, 4, 5, 6), "trials": 2}
A_LABEL = "heuristic · ablation none · paper · horizon 30"
B_LABEL = "heuristic · ablation none · paper · horizon 40"
C_LABEL = "heuristic · ablation none · paper"

# arm A (horizon 30) ran objects 3, 4, 5; arm B (horizon 40) objects 4, 5, 6; both with seeds 0 and 1:
# they share 4/0, 4/1, 5/0, 5/1. Per episode: (success, TS, AS)
A = {
    "3/0": (True, 9, 5),
    "3/1": (True, 11, 6),
    "4/0": (True, 10, 5),
    "4/1": (True, 12, 6),
    "5/0": (False, 30, 7),
    "5/1": (True, 8, 8),
}
B = {
    "4/0": (False, 40, 6),
    "4/1": (True, 12, 6),
    "5/0": (False, 40, 9),
    "5/1": (False, 40, 8),
    "6/0": (True, 20, 10),
    "6/1": (True, 21, 11),
}
SHARED = ["4/0", "4/1", "5/0", "5/1"]


def _row(scene: str, episode: str, horizon: int, result: tuple[bool, int, int]) -> dict[str, Any]:
    n, seed = (int(x) for x in episode.split("/"))
    ok, ts, steps = result
    key = f"pack_objects/{scene}/{n}/{seed}"
    return {
        "key": key,
        "method": "heuristic",
        "ablation": "none",
        "task": "pack_objects",
        "scene": scene,
        "seed": seed,
        "n_objects": n,
        "robots": ["alice", "bob", "david"],
        "reason": "success" if ok else "horizon",
        "success": ok,
        "placed": n if ok else 1,
        "total": n,
        "partial_success": 1.0 if ok else 1 / n,
        "temporal_steps": ts,
        "action_steps": 2 * steps,
        "action_steps_per_robot": {"alice": steps, "bob": steps, "david": 0},
        "active_ticks": steps,
        "fidelity": "paper",
        "horizon": horizon,
        "schedule": "sequential",
        "trace": f"traces/{key.replace('/', '_')}.jsonl",
    }


def _evaluation(d: Path, horizon: int, results: dict[str, tuple[bool, int, int]], scene: str = "kitchen") -> Path:
    spec = EvalSpec(**{**GRID, "scenes": (scene,)}, horizon=horizon)  # type: ignore[arg-type]
    (d / "traces").mkdir(parents=True)
    (d / "eval.json").write_text(EvalManifest(identity=spec.identity(), spec=spec).text())
    rows = [_row(scene, e, horizon, r) for e, r in results.items()]
    (d / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return d


@pytest.fixture
def dirs(tmp_path: Path) -> tuple[Path, Path, Path]:
    a = _evaluation(tmp_path / "a", 30, A)
    b = _evaluation(tmp_path / "b", 40, B)
    c = _evaluation(tmp_path / "c", 50, {"3/0": (True, 9, 5)}, scene="bedroom")  # shares no episode
    return a, b, c


def _report(*args: str) -> str:
    result = CliRunner().invoke(main, ["report", *args, "--resamples", "500"])
    assert result.exit_code == 0, result.output
    return result.stdout


def _ci(diffs: list[float], resamples: int = 500) -> tuple[float, float]:
    """The percentile bootstrap of the mean paired difference, by hand: resample the episodes."""
    x = np.array(diffs)
    idx = np.random.default_rng(0).integers(0, len(x), size=(resamples, len(x)))
    lo, hi = np.percentile(x[idx].mean(axis=1), [2.5, 97.5])
    return float(lo), float(hi)


def test_the_paired_figures_of_two_arms_equal_a_hand_computation(dirs: tuple[Path, Path, Path]) -> None:
    a, b, _ = dirs
    md = _report(str(a), str(b))
    section = md.split("## Paired comparisons")[1].split("\n## ")[0]
    # TS A - B over 4/0, 4/1, 5/0, 5/1: 10-40, 12-12, 30-40, 8-40 = -30, 0, -10, -32 -> mean -18
    ts = [A[e][1] - B[e][1] for e in SHARED]
    steps = [A[e][2] - B[e][2] for e in SHARED]  # 5-6, 6-6, 7-9, 8-8 = -1, 0, -2, 0 -> mean -0.75
    assert (ts, steps) == ([-30, 0, -10, -32], [-1, 0, -2, 0])
    (ts_lo, ts_hi), (as_lo, as_hi) = _ci(ts), _ci(steps)
    # discordant: A alone solved 4/0 and 5/1, B alone none: exact McNemar p = 2 * (1/2)^2 = 0.5
    row = (
        f"| {A_LABEL} | {B_LABEL} | 4 | 2 / 2 | -18.00 [{ts_lo:+.2f}, {ts_hi:+.2f}] | "
        f"-0.75 [{as_lo:+.2f}, {as_hi:+.2f}] | 2 | 0 | 0.5000 |"
    )
    assert row in section, section
    assert (
        f"- {A_LABEL} vs {B_LABEL}: paired pack_objects/kitchen/4/0, pack_objects/kitchen/4/1, "
        "pack_objects/kitchen/5/0, pack_objects/kitchen/5/1; left out: pack_objects/kitchen/3/0 (only A), "
        "pack_objects/kitchen/3/1 (only A), pack_objects/kitchen/6/0 (only B), pack_objects/kitchen/6/1 (only B)"
    ) in section
    assert "500 resamples of the paired episodes, seed 0" in section


def test_arms_without_a_shared_episode_are_skipped_in_one_line_and_the_files_carry_it(
    dirs: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    md = _report(*map(str, dirs))
    section = md.split("## Paired comparisons")[1].split("\n## ")[0]
    assert section.count(f"| {A_LABEL} | {B_LABEL} | 4 |") == 1 and section.count("\n| heuristic") == 1
    assert f"Skipped {A_LABEL} vs {C_LABEL}: no episode in common." in section  # arms in table order
    assert f"Skipped {B_LABEL} vs {C_LABEL}: no episode in common." in section
    out = tmp_path / "r.md"
    result = CliRunner().invoke(main, ["report", *map(str, dirs), "--resamples", "500", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_text() == md.removesuffix("\n")  # the file is what stdout shows
    assert "<h2>Paired comparisons</h2>" in out.with_suffix(".html").read_text()


def test_compare_restricts_to_two_arms_named_by_label_or_part_of_it(dirs: tuple[Path, Path, Path]) -> None:
    everything = _report(*map(str, dirs))
    two = _report(*map(str, dirs), "--compare", "horizon 30", B_LABEL)
    section = two.split("## Paired comparisons")[1].split("\n## ")[0]
    assert f"| {A_LABEL} | {B_LABEL} | 4 |" in section and "Skipped" not in section
    assert two.split("## Paired comparisons")[0] == everything.split("## Paired comparisons")[0]
    alone = _report(*map(str, dirs), "--compare", "horizon 40", C_LABEL)
    section = alone.split("## Paired comparisons")[1].split("\n## ")[0]
    assert f"Skipped {B_LABEL} vs {C_LABEL}: no episode in common." in section and "| A | B |" not in section


@pytest.mark.parametrize(
    ("names", "says"),
    [
        (("horizon 30", "horizon 60"), "--compare: no arm is named 'horizon 60' (arms: "),
        (("paper", "horizon 40"), "--compare: 'paper' names 3 arms ("),
        (("horizon 30", "horizon 30"), "name the same arm"),
    ],
    ids=["unknown", "ambiguous", "the same"],
)
def test_compare_refuses_a_name_that_is_no_arm_in_one_line(
    dirs: tuple[Path, Path, Path], names: tuple[str, str], says: str
) -> None:
    result = CliRunner().invoke(main, ["report", *map(str, dirs), "--compare", *names])
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error")]
    assert result.exit_code == 2 and len(errors) == 1 and says in errors[0], result.stderr
    assert "Traceback" not in result.output


def test_one_arm_has_no_paired_section(dirs: tuple[Path, Path, Path]) -> None:
    assert "Paired comparisons" not in _report(str(dirs[0]))
