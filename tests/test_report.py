"""`mhrc.eval.report` on hand-built rows: bootstrap intervals, the paper's figures beside the
settings that match its configuration (and only those), invalid episodes left out."""

from __future__ import annotations

import csv
import io
import statistics
from typing import Any

import pytest

from mhrc.eval.paper import PAPER_FIGURES, paper_model

from mhrc.eval.report import summary_csv, summary_markdown

from mhrc.eval.rows import bootstrap_ci

SCENES = ("bathroom", "bedroom", "kitchen")
GPT4O_PACK = "0.92 / 0.96 / 32.67 / 25.00"  # Table I, GPT-4o, Pack Objects
GPT4O_PACK_NO_MOBILE = "0.92 / 0.94 / 37.00 / 28.33"  # Table II, w/o mobile robot


def _rows(method: str, *, ablation: str = "none", fidelity: str = "paper", task: str = "pack_objects", scenes: tuple[str, ...] = SCENES,
          objects: tuple[int, ...] = (3, 4, 5, 6), repeats: int = 1, horizon: int = 50, history_cap: int | None = None,
          schedule: str = "sequential") -> list[dict[str, Any]]:  # fmt: skip
    rows = []
    for repeat in range(repeats):
        for i, (scene, n) in enumerate((s, n) for s in scenes for n in objects):
            ok = (i + repeat) % 4 != 0
            rows.append({
                "key": f"{task}/{scene}/{n}/{repeat}", "method": method, "ablation": ablation, "fidelity": fidelity,
                "history_cap": history_cap, "horizon": horizon, "aids": [], "repeat": repeat, "trial": 0, "task": task,
                "scene": scene, "seed": repeat, "n_objects": n, "robots": ["alice", "bob", "david"], "success": ok,
                "partial_success": 1.0 if ok else (i % 3) / 3, "temporal_steps": 20 + i if ok else horizon,
                "action_steps": 15 + i, "lower_bound": 9, "messages": 2, "llm_calls": 90, "prompt_tokens": 9000,
                "completion_tokens": 700, "failed_actions": {"pick": i % 2}, "wall_time": 1.0, "parse_failures": i % 2,
                "llm_unreachable": 0, "rejected_actions": 0, "valid": True, "invalid_reason": None, "schedule": schedule,
            })  # fmt: skip
    return rows


def test_the_bootstrap_interval_is_deterministic_and_contains_the_mean() -> None:
    values = [1, 0, 1, 1, 0, 1, 1, 1, 0, 1, 1, 0]
    lo, hi = bootstrap_ci(values)
    assert (lo, hi) == bootstrap_ci(values) == bootstrap_ci(values, resamples=2000, seed=0)
    assert lo <= statistics.fmean(values) <= hi and 0 <= lo < hi <= 1
    steps = [31.0, 50.0, 27.0, 44.0, 50.0, 38.0, 29.0, 50.0, 35.0, 41.0, 33.0, 47.0]
    assert bootstrap_ci(steps, seed=1) != bootstrap_ci(steps)  # the seed is what makes it repeatable
    assert bootstrap_ci([0.4, 0.4, 0.4]) == pytest.approx((0.4, 0.4))
    wide, narrow = bootstrap_ci(values, level=0.99), bootstrap_ci(values, level=0.5)
    assert wide[0] <= lo <= narrow[0] and narrow[1] <= hi <= wide[1]
    for xs in ([3.0, 50.0, 41.0, 27.5, 50.0, 33.0], [0.25, 0.5, 1.0, 1.0]):
        a, b = bootstrap_ci(xs)
        assert a <= statistics.fmean(xs) <= b
    with pytest.raises(ValueError):
        bootstrap_ci([])


@pytest.mark.parametrize(
    ("method", "model"),
    [
        ("openai:gpt-4o", "GPT-4o"),
        ("azure:GPT-4o-2024-08-06", "GPT-4o"),
        ("openai:gpt-4o-mini", None),
        ("openai:gpt-3.5-turbo", "GPT-3.5-turbo"),
        ("openai:gpt-3.5-turbo-0125", "GPT-3.5-turbo"),
        ("ollama:llama3.1:8b", "Llama-3.1-8B"),
        ("vllm:meta-llama/Llama-3.1-8B-Instruct", "Llama-3.1-8B"),
        ("ollama:llama3.1:70b", None),
        ("ollama:qwen2.5:7b", None),
        ("heuristic", None),
        ("replay:runs/gpt-4o", None),
    ],
)
def test_models_are_matched_loosely(method: str, model: str | None) -> None:
    assert paper_model(method) == model


def test_paper_figures_stand_beside_a_matching_setting_and_nowhere_else() -> None:
    rows = _rows("openai:gpt-4o") + _rows("openai:gpt-4o", ablation="no_mobile")
    text = summary_markdown(rows)
    assert "| paper GPT-4o (Table I) |" in text and GPT4O_PACK in text
    assert "paper GPT-4o w/o mobile robot (Table II)" in text and GPT4O_PACK_NO_MOBILE in text
    assert "0.92 / 0.94 / 37.00 / 28.33 (paper GPT-4o w/o mobile robot, Table II)" in text  # beside the CIs too
    # the same grid with repeats is still the paper's grid
    assert GPT4O_PACK in summary_markdown(_rows("openai:gpt-4o", repeats=2))
    row = next(r for r in csv.DictReader(io.StringIO(summary_csv(rows))) if r["ablation"] == "none")
    assert (row["paper_model"], row["paper_succ"], row["paper_as"]) == ("GPT-4o", "0.92", "25.0")
    assert float(row["succ_lo"]) <= float(row["succ"]) <= float(row["succ_hi"])

    not_matching = {
        "another model": (_rows("openai:gpt-4o-mini"), ""),
        "the heuristic": (_rows("heuristic"), ""),
        "aided": (_rows("openai:gpt-4o", fidelity="aids:goal_map"), "fidelity aids:goal_map, not paper"),
        "unrecorded fidelity": (_rows("openai:gpt-4o", fidelity="unrecorded"), "fidelity unrecorded, not paper"),
        "capped histories": (_rows("openai:gpt-4o", history_cap=12000), "history cap 12000"),
        "another horizon": (_rows("openai:gpt-4o", horizon=30), "horizon 30, the paper's is 50"),
        "lockstep": (_rows("openai:gpt-4o", schedule="lockstep"), "the lockstep schedule (the paper's robots act one after another"),
        "async": (_rows("openai:gpt-4o", schedule="async"), "the async schedule"),
        "rows from before schedules were recorded (lockstep)": (
            [{k: v for k, v in r.items() if k != "schedule"} for r in _rows("openai:gpt-4o")], "the lockstep schedule"),
        "two scenes": (_rows("openai:gpt-4o", scenes=SCENES[:2]), "not the paper grid: 2 scene(s)"),
        "other object counts": (_rows("openai:gpt-4o", objects=(3, 4)), "not the paper grid: scene bathroom has object counts 3, 4"),
        "an ablation Llama was not run with": (_rows("ollama:llama3.1:8b", ablation="no_feedback"), "reports no pack_objects figures for Llama-3.1-8B"),
    }
    for what, (mine, why) in not_matching.items():
        text = summary_markdown(mine)
        assert "(Table I)" not in text and "(Table II)" not in text and GPT4O_PACK not in text, what
        assert why in text, what
        assert all(r["paper_model"] == "" for r in csv.DictReader(io.StringIO(summary_csv(mine)))), what

    # side by side, each setting gets only its own match
    both = _rows("openai:gpt-4o") + _rows("openai:gpt-4o", fidelity="aids:all") + _rows("ollama:llama3.1:8b")
    table_one = summary_markdown(both).split("## Table II")[0]
    header = next(line for line in table_one.splitlines() if line.startswith("| task |"))
    assert header == (
        "| task | ollama:llama3.1:8b · paper | paper Llama-3.1-8B (Table I) | openai:gpt-4o · aids:all | "
        "openai:gpt-4o · paper | paper GPT-4o (Table I) |"
    )
    assert "0.00 / 0.20 / 50.00 / 40.33" in table_one  # Llama-3.1-8B, Pack Objects


def test_every_paper_figure_is_there() -> None:
    assert len(PAPER_FIGURES) == 6 and all(sorted(v) == ["make_sandwich", "pack_objects", "sort_solids"] for v in PAPER_FIGURES.values())
    assert PAPER_FIGURES[("GPT-4o", "none")]["make_sandwich"] == (0.75, 0.81, 38.89, 31.11)
    assert PAPER_FIGURES[("GPT-4o", "no_history")]["sort_solids"] == (0.0, 0.56, 50.0, 47.44)


def test_invalid_episodes_are_left_out_and_named_and_paper_and_aided_numbers_never_mix() -> None:
    rows = _rows("openai:gpt-4o") + _rows("openai:gpt-4o", fidelity="aids:goal_map")
    rows[0] |= {"valid": False, "invalid_reason": "the model was unreachable for all 90 LLM steps", "success": True}
    text = summary_markdown(rows)
    assert "24 episodes, 23 valid, 1 invalid." in text
    assert "- pack_objects/bathroom/3/0 (openai:gpt-4o · ablation none · paper): the model was unreachable for all 90 LLM steps" in text
    assert "| pack_objects | 11 |" in text and "| pack_objects | 12 |" in text  # one left out, and never pooled with the aided 12
    assert "not the paper grid" in text and GPT4O_PACK not in text  # an incomplete grid is not compared
    lines = list(csv.DictReader(io.StringIO(summary_csv(rows))))
    assert sorted((r["fidelity"], r["episodes"], r["invalid_left_out"]) for r in lines) == [("aids:goal_map", "12", "0"), ("paper", "11", "1")]
    assert "No valid episodes" in summary_markdown(rows[:1])
    # rows written before the new fields existed still summarize (as unrecorded fidelity)
    old = [{k: v for k, v in r.items() if k not in {"fidelity", "history_cap", "horizon", "valid", "parse_failures", "llm_unreachable", "rejected_actions"}} for r in rows[1:12]]
    assert "| heuristic" not in summary_markdown(old) and "openai:gpt-4o · ablation none · unrecorded" in summary_markdown(old)
