"""The MHRC paper's own figures and configuration (Table I and II, its grid, horizon and loop),
and when a setting of mhrc's rows is the paper's, so its figures may stand beside ours.

The paper's figures stand beside a setting only when every robot runs the same model of the
paper's, by a spec that names that model and nothing else (`paper_model`), with the default
prompt templates, at the paper's fidelity and with every other field of the setting at the
paper's value (a field this module does not know, such as a new world setting, at the value a
row without that field gets), on the paper's grid. Otherwise `PaperMatch.mismatches` says why,
as typed `Mismatch`es (a `Why` code and the values involved) that the summaries render."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

from mhrc.agents.llm.model_spec import PROVIDERS, LLMSpecError, robot_specs, split_url

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


PAPER_ABLATION_NAMES = {
    "none": "",
    "no_feedback": "w/o feedback",
    "no_history": "w/o history",
    "no_mobile": "w/o mobile robot",
}


PAPER_SCHEDULE = "sequential"  # Algorithm 1; rows written before the field ran lockstep


HEURISTIC = "heuristic"  # a row's method when no robot had a model (`mhrc eval` without --llm)


# --------------------------------------------------------------------------- the paper's model


# Which specs are the paper's models. GPT-4o and GPT-3.5-turbo exist only behind OpenAI's API:
# the provider `openai` (model id exactly gpt-4o, or a dated snapshot of it) sent to OpenAI's own
# URL, not to an `@URL` or a --base-url (any other server only says its model is so named).
# Llama-3.1-8B's weights are open, so a name that pins Meta's unquantised instruct weights counts
# on whatever server serves it: vLLM's Hugging Face repo id, or Ollama's fp16 tag. Ollama's
# `llama3.1:8b` (a 4-bit quantisation), any GGUF (`gguf:`, `llamacpp:`, `lmstudio:`) and replays
# are not the paper's model.
OPENAI_MODELS: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("GPT-4o", re.compile(r"gpt-4o(?:-\d{4}-\d{2}-\d{2})?")),
    ("GPT-3.5-turbo", re.compile(r"gpt-3\.5-turbo(?:-\d{4})?")),
)
OPEN_WEIGHTS: dict[
    str, tuple[str, re.Pattern[str]]
] = {  # provider -> (the paper's name, the model names that pin its weights)
    "vllm": ("Llama-3.1-8B", re.compile(r"meta-llama/(?:meta-)?llama-3\.1-8b-instruct", re.IGNORECASE)),
    "ollama": ("Llama-3.1-8B", re.compile(r"llama3\.1:8b-instruct-fp16")),
}
LLAMA_LIKE = re.compile(r"llama-?3\.1[-_:]?8b", re.IGNORECASE)  # names Llama-3.1-8B, in some build or other
OPENAI_URL = PROVIDERS["openai"][0]


class Why(Enum):
    """Why the paper's figures do not stand beside a setting (per setting; the last two per task)."""

    HEURISTIC = "heuristic"  # robots run the heuristic policy
    REPLAY = "replay"  # robots replay a recorded trace
    LOCAL_FILE = "local_file"  # robots run a local GGUF file
    OTHER_SERVER = "other_server"  # a GPT model's name, asked of a server other than OpenAI's API
    OTHER_BUILD = "other_build"  # a Llama-3.1-8B that is not the unquantised instruct weights
    OTHER_MODEL = "other_model"  # a model the paper does not report
    MIXED_MODELS = "mixed_models"  # every robot runs a paper model, not all the same one
    CUSTOM_PROMPTS = "custom_prompts"  # --prompts: the user's own templates
    FIDELITY = "fidelity"
    MODE = "mode"
    HISTORY_CAP = "history_cap"
    HORIZON = "horizon"
    SCENARIO = "scenario"
    SCHEDULE = "schedule"
    TEAM = "team"  # a team other than the paper's Alice, Bob and David
    PROTOCOL = "protocol"  # a coordination protocol other than the paper's (mhrc)
    SETTING = "setting"  # another field of the setting (a world setting) not at its default
    NO_FIGURES = "no_figures"  # the paper reports no figures for this model, ablation and task
    GRID = "grid"  # not the paper's grid of scenes and object counts


PER_TASK = frozenset({Why.NO_FIGURES, Why.GRID})


# the setting's fields with the paper's value and the reason a different value gives (method and
# ablation are the team's and the figures' business); any other field of the setting must hold
# the value a row without that field gets
PAPER_SETTING: dict[str, tuple[Any, Why]] = {
    "fidelity": ("paper", Why.FIDELITY),
    "mode": ("free", Why.MODE),
    "history_cap": (None, Why.HISTORY_CAP),
    "horizon": (PAPER_HORIZON, Why.HORIZON),
    "scenario": (None, Why.SCENARIO),
    "schedule": (PAPER_SCHEDULE, Why.SCHEDULE),
    "team": (None, Why.TEAM),
    "protocol": (None, Why.PROTOCOL),
}
TEAM_FIELDS = frozenset({"method", "ablation"})


@dataclass(frozen=True)
class Mismatch:
    """One reason, typed: `why`, and the values the sentence names (`robots` and `value` for the
    team's reasons, `field` and `value` for a setting's field, `value` alone otherwise)."""

    why: Why
    value: str = ""
    robots: tuple[str, ...] = ()
    every: bool = False  # `robots` is the whole team
    field: str = ""
    default: str = ""

    @property
    def per_task(self) -> bool:
        return self.why in PER_TASK

    def text(self) -> str:
        who = "every robot" if self.every and len(self.robots) > 1 else _names(self.robots)
        one = self.every or len(self.robots) == 1
        run, ask, replay = ("runs", "asks", "replays") if one else ("run", "ask", "replay")
        match self.why:
            case Why.HEURISTIC:
                return f"{who} {run} the heuristic, not the paper's model"
            case Why.REPLAY:
                return f"{who} {replay} a recorded trace ({self.value}), not the paper's model"
            case Why.LOCAL_FILE:
                return f"{who} {run} a local GGUF file ({self.value}), not the paper's model"
            case Why.OTHER_SERVER:
                return f"{who} {ask} {self.value}: a server other than OpenAI's API, so not the paper's model"
            case Why.OTHER_BUILD:
                return f"{who} {run} {self.value}, not Meta's unquantised Llama-3.1-8B-Instruct (the paper's model)"
            case Why.OTHER_MODEL:
                return f"{who} {run} {self.value}, not a model the paper reports"
            case Why.MIXED_MODELS:
                return f"the robots run different models ({self.value}); the paper runs one model for the whole team"
            case Why.CUSTOM_PROMPTS:
                return f"custom prompt templates (--prompts {self.value}), not the paper's"
            case Why.FIDELITY:
                return f"fidelity {self.value}, not paper"
            case Why.MODE:
                return f"{self.value} decisions (the paper's model answers in free text)"
            case Why.HISTORY_CAP:
                return f"history cap {self.value} (the paper keeps whole histories)"
            case Why.HORIZON:
                return f"horizon {self.value}, the paper's is {PAPER_HORIZON}"
            case Why.SCENARIO:
                return f"scenario {self.value} (the paper's episodes are static)"
            case Why.SCHEDULE:
                return (
                    f"the {self.value} schedule (the paper's robots act one after another: --schedule {PAPER_SCHEDULE})"
                )
            case Why.TEAM:
                return f"the team {self.value}, not the paper's Alice, Bob and David"
            case Why.PROTOCOL:
                return f"the {self.value} protocol, not the paper's (each robot its own agent: mhrc)"
            case Why.SETTING:
                return f"{self.field} {self.value}, not the default {self.default}"
            case Why.NO_FIGURES:
                return self.value
            case Why.GRID:
                return f"not the paper grid: {self.value}"


def _names(robots: Sequence[str]) -> str:
    return ", ".join(robots[:-1]) + (" and " if len(robots) > 1 else "") + "".join(robots[-1:])


@dataclass(frozen=True)
class Verdict:
    """What one robot's spec is: the paper's name of its model, or why it is not one."""

    model: str | None
    why: Why | None = None


def judge_spec(spec: str | None, base_url: str | None = None) -> Verdict:
    """Whether a robot's spec (None: the heuristic) is a model of the paper's, asked where that
    model is (`base_url`: the run's --base-url, which a spec's own @URL overrides)."""
    if spec is None:
        return Verdict(None, Why.HEURISTIC)
    bare, own_url = split_url(spec.strip())
    url = own_url or base_url
    provider, _, name = bare.partition(":")
    if provider == "replay":
        return Verdict(None, Why.REPLAY)
    if provider == "gguf":
        return Verdict(None, Why.LOCAL_FILE)
    if provider not in PROVIDERS:
        provider, name = "", bare  # with a base URL, a spec without a known provider is the model name
    gpt = next((paper for paper, pattern in OPENAI_MODELS if pattern.fullmatch(name)), None)
    if gpt is not None:
        at_openai = provider == "openai" and (url is None or url.rstrip("/") == OPENAI_URL)
        return Verdict(gpt, None) if at_openai else Verdict(None, Why.OTHER_SERVER)
    paper, weights = OPEN_WEIGHTS.get(provider, ("", None))
    if weights is not None and weights.fullmatch(name):
        return Verdict(paper, None)
    return Verdict(None, Why.OTHER_BUILD if LLAMA_LIKE.search(name) else Why.OTHER_MODEL)


def paper_model(spec: str | None, base_url: str | None = None) -> str | None:
    """The paper's name of the model one spec runs (GPT-4o, GPT-3.5-turbo, Llama-3.1-8B), or None."""
    return judge_spec(spec, base_url).model


@dataclass(frozen=True)
class Ran:
    """What one episode's row ran, as far as the paper's figures care (mhrc.eval.summary makes it of a row)."""

    method: str
    robots: tuple[str, ...]
    scene: str
    n_objects: int
    prompts: str | None = None
    base_url: str | None = None


def team_mismatches(row: Ran) -> tuple[str | None, tuple[Mismatch, ...]]:
    """The paper's model every robot of a row runs, or the reasons they do not run one model of
    the paper's with its prompts (its `method`, `robots`, `prompts` and `base_url`)."""
    robots, method = row.robots, row.method or HEURISTIC
    specs: dict[str, str | None]
    try:
        specs = dict.fromkeys(robots) if method == HEURISTIC else robot_specs(method, robots)
    except LLMSpecError:  # a method that names robots this row does not have
        specs = {r: method for r in robots}
    base_url = row.base_url
    verdicts = {r: judge_spec(s, base_url) for r, s in specs.items()}
    found: list[Mismatch] = []
    groups: dict[tuple[Why, str], list[str]] = {}
    for r, v in verdicts.items():
        if v.why is not None:
            groups.setdefault((v.why, str(specs[r] or "")), []).append(r)
    for (why, spec), mine in groups.items():
        found.append(Mismatch(why, spec, tuple(mine), every=len(mine) == len(robots)))
    model = None
    if not found and robots:
        if len(set(specs.values())) == 1:
            model = verdicts[robots[0]].model
        else:
            found.append(Mismatch(Why.MIXED_MODELS, ", ".join(f"{r} {specs[r]}" for r in robots)))
    if row.prompts:
        found.append(Mismatch(Why.CUSTOM_PROMPTS, row.prompts))
    return (model if not found else None), tuple(found)


def setting_mismatches(setting: Mapping[str, Any], defaults: Mapping[str, Any]) -> tuple[Mismatch, ...]:
    """Every field of a setting (but method and ablation) that is not the paper's value:
    PAPER_SETTING's, or for any other field `defaults`' (the value a row without it gets)."""
    found = []
    for name in [*PAPER_SETTING, *(f for f in setting if f not in PAPER_SETTING)]:
        if name in TEAM_FIELDS or name not in setting:
            continue
        paper, why = PAPER_SETTING.get(name, (defaults.get(name), Why.SETTING))
        if setting[name] != paper:
            found.append(Mismatch(why, str(setting[name]), field=name, default=str(paper)))
    return tuple(found)


@dataclass(frozen=True)
class PaperMatch:
    model: str | None  # the paper's model every robot runs; None when they do not run one
    ablation: str
    figures: Figures | None  # None: the configuration does not match, `mismatches` say how
    mismatches: tuple[Mismatch, ...] = ()

    @property
    def title(self) -> str:
        extra = PAPER_ABLATION_NAMES.get(self.ablation, self.ablation)
        return f"paper {self.model}" + (f" {extra}" if extra else "")

    @property
    def table(self) -> str:
        return "Table I" if self.ablation == "none" else "Table II"

    @property
    def why(self) -> str:
        return "; ".join(m.text() for m in self.mismatches)


def grid_problem(rows: Sequence[Ran]) -> str | None:
    """Why these rows (one setting, one task) are not the paper grid, or None if they are."""
    cells = Counter((r.scene, r.n_objects) for r in rows)
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


def paper_match(setting: Mapping[str, Any], task: str, rows: Sequence[Ran], defaults: Mapping[str, Any]) -> PaperMatch:
    """The paper's figures for this setting (field name -> value) and task when every row's team
    and the configuration match; otherwise a PaperMatch without figures and every reason:
    the team's (the first row whose team differs from the paper's) and the setting's, then
    (only for a team and setting that match) the task's. `defaults`: each setting field's value
    in a row that lacks it."""
    ablation = str(setting["ablation"])
    teams = [team_mismatches(r) for r in rows]
    model = teams[0][0] if teams else None
    found = next((why for _, why in teams if why), ())
    if not found and len({m for m, _ in teams}) > 1:  # merged runs of one method cannot differ, but say so if they do
        found = (Mismatch(Why.MIXED_MODELS, ", ".join(sorted({str(m) for m, _ in teams}))),)
    found += setting_mismatches(setting, defaults)
    if found:
        return PaperMatch(model, ablation, None, found)
    figures = PAPER_FIGURES.get((str(model), ablation), {}).get(task)
    if figures is None:
        why = Mismatch(Why.NO_FIGURES, f"the paper reports no {task} figures for {model} with ablation {ablation}")
        return PaperMatch(model, ablation, None, (why,))
    if grid := grid_problem(rows):
        return PaperMatch(model, ablation, None, (Mismatch(Why.GRID, grid),))
    return PaperMatch(model, ablation, figures)


def paper_cell(f: Figures) -> str:
    return f"{f[0]:.2f} / {f[1]:.2f} / {f[2]:.2f} / {f[3]:.2f}"
