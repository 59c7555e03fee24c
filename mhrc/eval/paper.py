"""The MHRC paper's own figures and configuration (Table I and II, its grid, horizon and loop),
and when a setting of mhrc's rows is the paper's, so its figures may stand beside ours."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from typing import Any


PAPER_OBJECTS = (3, 4, 5, 6)  # one episode per object count per scene


PAPER_SCENES = 3


PAPER_HORIZON = 50


# The MHRC paper's figures (Succ, PS, TS, AS per task), as /work/shared/PAPER.md transcribes
# them from the paper (seed/000_027b806dfa4f6e57.txt): Table I, "MHRC with each LLM" (ablation
# none), and Table II, "GPT-4o ablations" (w/o feedback, w/o history, w/o mobile robot; its
# "full" column repeats Table I's GPT-4o). Keys: (the paper's model, mhrc's ablation name).
Figures = tuple[float, float, float, float]


PAPER_FIGURES: dict[tuple[str, str], dict[str, Figures]] = {
    ("GPT-3.5-turbo", "none"): {
        "make_sandwich": (0.0, 0.14, 50.0, 41.22),
        "sort_solids": (0.0, 0.17, 50.0, 39.89),
        "pack_objects": (0.0, 0.25, 50.0, 37.67),
    },
    ("Llama-3.1-8B", "none"): {
        "make_sandwich": (0.0, 0.12, 50.0, 46.00),
        "sort_solids": (0.0, 0.14, 50.0, 44.33),
        "pack_objects": (0.0, 0.20, 50.0, 40.33),
    },
    ("GPT-4o", "none"): {
        "make_sandwich": (0.75, 0.81, 38.89, 31.11),
        "sort_solids": (0.83, 0.88, 34.56, 27.33),
        "pack_objects": (0.92, 0.96, 32.67, 25.00),
    },
    ("GPT-4o", "no_feedback"): {
        "make_sandwich": (0.0, 0.08, 50.0, 48.56),
        "sort_solids": (0.0, 0.10, 50.0, 46.22),
        "pack_objects": (0.0, 0.14, 50.0, 46.00),
    },
    ("GPT-4o", "no_history"): {
        "make_sandwich": (0.0, 0.48, 50.0, 46.89),
        "sort_solids": (0.0, 0.56, 50.0, 47.44),
        "pack_objects": (0.0, 0.61, 50.0, 48.33),
    },
    ("GPT-4o", "no_mobile"): {
        "make_sandwich": (0.69, 0.78, 44.67, 36.33),
        "sort_solids": (0.81, 0.84, 40.50, 31.17),
        "pack_objects": (0.92, 0.94, 37.00, 28.33),
    },
}


PAPER_ABLATION_NAMES = {"none": "", "no_feedback": "w/o feedback", "no_history": "w/o history", "no_mobile": "w/o mobile robot"}


# How a method's model spec is recognised as one the paper ran (lower-cased, matched loosely:
# openai:gpt-4o, azure:gpt-4o-2024-08-06, ollama:llama3.1:8b, vllm:meta-llama/Llama-3.1-8B-Instruct).
PAPER_MODELS: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("GPT-4o", re.compile(r"gpt-?4o(?:-\d{4}-\d{2}-\d{2})?$")),
    ("GPT-3.5-turbo", re.compile(r"gpt-?3\.5-turbo(?:-\d{4})?$")),
    ("Llama-3.1-8B", re.compile(r"llama-?3\.1[-_:]?8b")),
)


PAPER_SCHEDULE = "sequential"  # Algorithm 1; rows written before the field ran lockstep


def paper_model(method: str) -> str | None:
    """The paper's name of the model a method runs (GPT-4o, GPT-3.5-turbo, Llama-3.1-8B), or None."""
    spec = method.strip().lower()
    if spec.startswith("replay:"):
        return None
    return next((name for name, pattern in PAPER_MODELS if pattern.search(spec)), None)


@dataclass(frozen=True)
class PaperMatch:
    model: str
    ablation: str
    figures: Figures | None  # None: the configuration does not match, `why` says how
    why: str = ""

    @property
    def title(self) -> str:
        extra = PAPER_ABLATION_NAMES.get(self.ablation, self.ablation)
        return f"paper {self.model}" + (f" {extra}" if extra else "")

    @property
    def table(self) -> str:
        return "Table I" if self.ablation == "none" else "Table II"


def grid_problem(rows: list[dict[str, Any]]) -> str | None:
    """Why these rows (one setting, one task) are not the paper grid, or None if they are."""
    cells = Counter((r["scene"], r["n_objects"]) for r in rows)
    scenes = sorted({s for s, _ in cells})
    if len(scenes) != PAPER_SCENES:
        return f"{len(scenes)} scene(s), the paper has {PAPER_SCENES}"
    for scene in scenes:
        counts = sorted({n for s, n in cells if s == scene})
        if counts != list(PAPER_OBJECTS):
            return f"scene {scene} has object counts {', '.join(map(str, counts))}, the paper {', '.join(map(str, PAPER_OBJECTS))}"
    if len(set(cells.values())) != 1:
        return "unequal numbers of episodes per scene and object count"
    return None


def paper_match(setting: tuple[Any, ...], task: str, rows: list[dict[str, Any]]) -> PaperMatch | None:
    """The paper's figures for this setting and task when the configuration matches; a
    PaperMatch without figures (and the reason) when only the model matches; None otherwise."""
    method, ablation, fidelity, cap, horizon, mode, schedule, scenario = setting
    model = paper_model(str(method))
    if model is None:
        return None
    figures = PAPER_FIGURES.get((model, ablation), {}).get(task)
    if figures is None:
        return PaperMatch(model, ablation, None, f"the paper reports no {task} figures for {model} with ablation {ablation}")
    why = ""
    if fidelity != "paper":
        why = f"fidelity {fidelity}, not paper"
    elif mode != "free":
        why = f"{mode} decisions (the paper's model answers in free text)"
    elif cap is not None:
        why = f"history cap {cap} (the paper keeps whole histories)"
    elif horizon != PAPER_HORIZON:
        why = f"horizon {horizon}, the paper's is {PAPER_HORIZON}"
    elif scenario is not None:
        why = f"scenario {scenario} (the paper's episodes are static)"
    elif schedule != PAPER_SCHEDULE:
        why = f"the {schedule} schedule (the paper's robots act one after another: --schedule {PAPER_SCHEDULE})"
    else:
        why = grid_problem(rows) or ""
        if why:
            why = "not the paper grid: " + why
    return PaperMatch(model, ablation, None if why else figures, why)


def paper_cell(f: Figures) -> str:
    return f"{f[0]:.2f} / {f[1]:.2f} / {f[2]:.2f} / {f[3]:.2f}"
