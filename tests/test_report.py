"""`mhrc.eval.report` on hand-built rows: bootstrap intervals, the paper's figures beside the
settings that match its configuration (and only those), invalid episodes left out."""

from __future__ import annotations

import csv
import io
import statistics
from typing import Any

import pytest

from mhrc.eval import html, report
from mhrc.eval.paper import PAPER_FIGURES, Why, paper_match, paper_model
from mhrc.eval.records import EvalRow, upgrade_row
from mhrc.eval.rows import bootstrap_ci
from mhrc.eval.summary import ran


def _typed(rows: list[dict[str, Any]]) -> list[EvalRow]:
    """Rows as episodes.jsonl holds them, read (mhrc.eval.records.upgrade_row)."""
    return [upgrade_row(r) for r in rows]


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    return report.summary_markdown(_typed(rows))


def summary_csv(rows: list[dict[str, Any]]) -> str:
    return report.summary_csv(_typed(rows))


def html_summary(rows: list[dict[str, Any]], links: list[str | None]) -> str:
    return html.html_summary(_typed(rows), links)


SCENES = ("bathroom", "bedroom", "kitchen")
GPT4O_PACK = "0.92 / 0.96 / 32.67 / 25.00"  # Table I, GPT-4o, Pack Objects
GPT4O_PACK_NO_MOBILE = "0.92 / 0.94 / 37.00 / 28.33"  # Table II, w/o mobile robot


def _rows(
    method: str,
    *,
    ablation: str = "none",
    fidelity: str = "paper",
    task: str = "pack_objects",
    scenes: tuple[str, ...] = SCENES,
    objects: tuple[int, ...] = (3, 4, 5, 6),
    repeats: int = 1,
    horizon: int = 50,
    history_cap: int | None = None,
    schedule: str = "sequential",
    **extra: Any,
) -> list[dict[str, Any]]:
    rows = []
    for repeat in range(repeats):
        for i, (scene, n) in enumerate((s, n) for s in scenes for n in objects):
            ok = (i + repeat) % 4 != 0
            rows.append(
                {
                    "key": f"{task}/{scene}/{n}/{repeat}",
                    "method": method,
                    "ablation": ablation,
                    "fidelity": fidelity,
                    "history_cap": history_cap,
                    "horizon": horizon,
                    "aids": [],
                    "repeat": repeat,
                    "trial": 0,
                    "task": task,
                    "scene": scene,
                    "seed": repeat,
                    "n_objects": n,
                    "robots": ["alice", "bob", "david"],
                    "reason": "success" if ok else "horizon",
                    "placed": n if ok else 0,
                    "total": n,
                    "action_steps_per_robot": {},
                    "success": ok,
                    "partial_success": 1.0 if ok else (i % 3) / 3,
                    "temporal_steps": 20 + i if ok else horizon,
                    "action_steps": 15 + i,
                    "lower_bound": 9,
                    "messages": 2,
                    "llm_calls": 90,
                    "prompt_tokens": 9000,
                    "completion_tokens": 700,
                    "failed_actions": {"pick": i % 2},
                    "wall_time": 1.0,
                    "parse_failures": i % 2,
                    "llm_unreachable": 0,
                    "rejected_actions": 0,
                    "valid": True,
                    "invalid_reason": None,
                    "schedule": schedule,
                }
                | extra
            )
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
    ("spec", "base_url", "model"),
    [
        ("openai:gpt-4o", None, "GPT-4o"),
        ("openai:gpt-4o-2024-08-06", None, "GPT-4o"),
        ("openai:gpt-4o@https://api.openai.com/v1/", None, "GPT-4o"),  # OpenAI's own URL, spelled out
        ("openai:gpt-4o", "https://api.openai.com/v1", "GPT-4o"),
        ("openai:gpt-4o-mini", None, None),
        ("openai:gpt-3.5-turbo", None, "GPT-3.5-turbo"),
        ("openai:gpt-3.5-turbo-0125", None, "GPT-3.5-turbo"),
        ("vllm:meta-llama/Llama-3.1-8B-Instruct", None, "Llama-3.1-8B"),
        (
            "vllm:meta-llama/Meta-Llama-3.1-8B-Instruct@http://gpu:8000/v1",
            None,
            "Llama-3.1-8B",
        ),  # open weights: any server
        ("ollama:llama3.1:8b-instruct-fp16", None, "Llama-3.1-8B"),
        # a server other than OpenAI's only says its model is called so
        ("openai:gpt-4o@http://127.0.0.1:8080/v1", None, None),
        ("openai:gpt-4o", "http://127.0.0.1:8080/v1", None),
        ("vllm:gpt-4o", None, None),
        ("azure:GPT-4o-2024-08-06", "https://example.openai.azure.com/v1", None),
        # quantised Llama builds and local files
        ("ollama:llama3.1:8b", None, None),  # Ollama's default tag is a 4-bit quantisation
        ("vllm:hugging-quants/Meta-Llama-3.1-8B-Instruct-AWQ-INT4", None, None),
        ("lmstudio:meta-llama-3.1-8b-instruct", None, None),
        ("gguf:models/Llama-3.1-8B-Instruct-Q4_K_M.gguf", None, None),
        ("ollama:llama3.1:70b", None, None),
        ("ollama:qwen2.5:7b", None, None),
        (None, None, None),  # the heuristic
        ("replay:runs/gpt-4o", None, None),
    ],
)
def test_which_specs_are_the_papers_models(spec: str | None, base_url: str | None, model: str | None) -> None:
    assert paper_model(spec, base_url) == model


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
        "lockstep": (
            _rows("openai:gpt-4o", schedule="lockstep"),
            "the lockstep schedule (the paper's robots act one after another",
        ),
        "async": (_rows("openai:gpt-4o", schedule="async"), "the async schedule"),
        "rows from before schedules were recorded (lockstep)": (
            [{k: v for k, v in r.items() if k != "schedule"} for r in _rows("openai:gpt-4o")],
            "the lockstep schedule",
        ),
        "two scenes": (_rows("openai:gpt-4o", scenes=SCENES[:2]), "not the paper grid: 2 scene(s)"),
        "other object counts": (
            _rows("openai:gpt-4o", objects=(3, 4)),
            "not the paper grid: scene bathroom has object counts 3, 4",
        ),
        "an ablation Llama was not run with": (
            _rows("vllm:meta-llama/Llama-3.1-8B-Instruct", ablation="no_feedback"),
            "reports no pack_objects figures for Llama-3.1-8B",
        ),
    }
    for what, (mine, why) in not_matching.items():
        text = summary_markdown(mine)
        assert "(Table I)" not in text and "(Table II)" not in text and GPT4O_PACK not in text, what
        assert why in text, what
        assert all(r["paper_model"] == "" for r in csv.DictReader(io.StringIO(summary_csv(mine)))), what

    # side by side, each setting gets only its own match
    both = (
        _rows("openai:gpt-4o") + _rows("openai:gpt-4o", fidelity="aids:all") + _rows("ollama:llama3.1:8b-instruct-fp16")
    )
    table_one = summary_markdown(both).split("## Table II")[0]
    header = next(line for line in table_one.splitlines() if line.startswith("| task |"))
    assert header == (
        "| task | ollama:llama3.1:8b-instruct-fp16 · paper | paper Llama-3.1-8B (Table I) | openai:gpt-4o · aids:all | "
        "openai:gpt-4o · paper | paper GPT-4o (Table I) |"
    )
    assert "0.00 / 0.20 / 50.00 / 40.33" in table_one  # Llama-3.1-8B, Pack Objects


NO_PAPER = "No paper figures beside this run: "


def _no_paper_cells(rows: list[dict[str, Any]]) -> str:
    """The summary of rows that must get no paper cells (markdown, CSV and HTML); its markdown."""
    text = summary_markdown(rows)
    assert "(Table I)" not in text and "(Table II)" not in text and "paper Succ" not in text and GPT4O_PACK not in text
    assert all(r["paper_model"] == "" for r in csv.DictReader(io.StringIO(summary_csv(rows))))
    return text


def test_the_papers_figures_stand_only_beside_a_whole_team_of_the_papers_model_with_its_prompts() -> None:
    """Issue 31: `--llm alice=openai:gpt-4o` (Bob and David the heuristic) was set beside the paper's GPT-4o."""
    for method in (
        "openai:gpt-4o",
        "alice=openai:gpt-4o,bob=openai:gpt-4o,david=openai:gpt-4o",
        "bob=openai:gpt-4o,openai:gpt-4o",
    ):
        text = summary_markdown(_rows(method))
        assert "paper GPT-4o (Table I)" in text and GPT4O_PACK in text and NO_PAPER not in text, method
    # w/o mobile robot: the team is Alice and Bob
    no_mobile = _rows("alice=openai:gpt-4o,bob=openai:gpt-4o", ablation="no_mobile", robots=["alice", "bob"])
    assert GPT4O_PACK_NO_MOBILE in summary_markdown(no_mobile)

    cases = {
        "alice=openai:gpt-4o": "bob and david run the heuristic, not the paper's model",
        "alice=openai:gpt-4o,bob=openai:gpt-4o": "david runs the heuristic, not the paper's model",
        "openai:gpt-4o,david=openai:gpt-3.5-turbo": (
            "the robots run different models (alice openai:gpt-4o, bob openai:gpt-4o, david openai:gpt-3.5-turbo); "
            "the paper runs one model for the whole team"
        ),
        "alice=openai:gpt-4o,bob=ollama:qwen2.5:7b": "bob runs ollama:qwen2.5:7b, not a model the paper reports; david runs the heuristic",
        "heuristic": "every robot runs the heuristic, not the paper's model",
    }
    for method, why in cases.items():
        assert why in _no_paper_cells(_rows(method)), method
    text = _no_paper_cells(_rows("alice=openai:gpt-4o"))
    line = next(x for x in text.splitlines() if x.startswith(NO_PAPER))
    assert (
        line == NO_PAPER + "bob and david run the heuristic, not the paper's model."
    )  # one line, in the setting's section
    assert text.index("### alice=openai:gpt-4o · ablation none · paper") < text.index(line)
    assert "<p>" + NO_PAPER + "bob and david run the heuristic, not the paper's model.</p>" in html_summary(
        _rows("alice=openai:gpt-4o"), [None] * 12
    )


@pytest.mark.parametrize(
    ("rows", "why"),
    [
        (
            _rows("openai:gpt-4o", prompts="my-prompts"),
            "custom prompt templates (--prompts my-prompts), not the paper's",
        ),
        (
            _rows("replay:runs/gpt4o/traces/a.jsonl"),
            "every robot replays a recorded trace (replay:runs/gpt4o/traces/a.jsonl), not the paper's model",
        ),
        (
            _rows("gguf:models/Llama-3.1-8B-Instruct-Q4_K_M.gguf"),
            "every robot runs a local GGUF file (gguf:models/Llama-3.1-8B-Instruct-Q4_K_M.gguf), not the paper's model",
        ),
        (
            _rows("ollama:llama3.1:8b"),
            "every robot runs ollama:llama3.1:8b, not Meta's unquantised Llama-3.1-8B-Instruct (the paper's model)",
        ),
        (
            _rows("openai:gpt-4o@http://127.0.0.1:8080/v1"),
            "every robot asks openai:gpt-4o@http://127.0.0.1:8080/v1: a server other than OpenAI's API, so not the paper's model",
        ),
        (
            _rows("openai:gpt-4o", base_url="http://127.0.0.1:8080/v1"),
            "every robot asks openai:gpt-4o: a server other than OpenAI's API",
        ),
        (
            _rows("alice=openai:gpt-4o", prompts="p", fidelity="aids:all"),  # every reason, in one line
            "bob and david run the heuristic, not the paper's model; custom prompt templates (--prompts p), not the paper's; fidelity aids:all, not paper.",
        ),
    ],
    ids=["prompts", "replay", "gguf", "quantised", "own URL", "base URL", "several"],
)
def test_a_run_that_is_not_the_papers_model_says_why_it_has_no_paper_cells(
    rows: list[dict[str, Any]], why: str
) -> None:
    assert NO_PAPER + why in _no_paper_cells(rows)


def test_any_other_setting_off_its_default_keeps_the_paper_figures_away() -> None:
    """A setting field this module does not know (a world setting such as noise) must hold the value a row without it gets."""
    fields = ("method", "ablation", "fidelity", "history_cap", "horizon", "mode", "schedule", "scenario", "noise")
    paper = ("openai:gpt-4o", "none", "paper", None, 50, "free", "sequential", None, None)
    rows, defaults = _rows("openai:gpt-4o"), dict.fromkeys(fields) | {"noise": None}
    assert (
        paper_match(dict(zip(fields, paper)), "pack_objects", [ran(r) for r in _typed(rows)], defaults).figures
        == PAPER_FIGURES[("GPT-4o", "none")]["pack_objects"]
    )
    noisy = paper_match(dict(zip(fields, (*paper[:-1], 0.1))), "pack_objects", [ran(r) for r in _typed(rows)], defaults)
    assert (
        noisy.figures is None
        and [m.why for m in noisy.mismatches] == [Why.SETTING]
        and noisy.why == "noise 0.1, not the default None"
    )


def test_every_paper_figure_is_there() -> None:
    assert len(PAPER_FIGURES) == 6 and all(
        sorted(v) == ["make_sandwich", "pack_objects", "sort_solids"] for v in PAPER_FIGURES.values()
    )
    assert PAPER_FIGURES[("GPT-4o", "none")]["make_sandwich"] == (0.75, 0.81, 38.89, 31.11)
    assert PAPER_FIGURES[("GPT-4o", "no_history")]["sort_solids"] == (0.0, 0.56, 50.0, 47.44)


def test_invalid_episodes_are_left_out_and_named_and_paper_and_aided_numbers_never_mix() -> None:
    rows = _rows("openai:gpt-4o") + _rows("openai:gpt-4o", fidelity="aids:goal_map")
    rows[0] |= {"valid": False, "invalid_reason": "the model was unreachable for all 90 LLM steps", "success": True}
    text = summary_markdown(rows)
    assert "24 episodes, 23 valid, 1 invalid." in text
    assert (
        "- pack_objects/bathroom/3/0 (openai:gpt-4o · ablation none · paper): the model was unreachable for all 90 LLM steps"
        in text
    )
    assert (
        "| pack_objects | 11 |" in text and "| pack_objects | 12 |" in text
    )  # one left out, and never pooled with the aided 12
    assert "not the paper grid" in text and GPT4O_PACK not in text  # an incomplete grid is not compared
    lines = list(csv.DictReader(io.StringIO(summary_csv(rows))))
    assert sorted((r["fidelity"], r["episodes"], r["invalid_left_out"]) for r in lines) == [
        ("aids:goal_map", "12", "0"),
        ("paper", "11", "1"),
    ]
    assert "No valid episodes" in summary_markdown(rows[:1])
    # rows written before the new fields existed still summarize (as unrecorded fidelity)
    old = [
        {
            k: v
            for k, v in r.items()
            if k
            not in {
                "fidelity",
                "history_cap",
                "horizon",
                "valid",
                "parse_failures",
                "llm_unreachable",
                "rejected_actions",
            }
        }
        for r in rows[1:12]
    ]
    assert "| heuristic" not in summary_markdown(
        old
    ) and "openai:gpt-4o · ablation none · unrecorded" in summary_markdown(old)
