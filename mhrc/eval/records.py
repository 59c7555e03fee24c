"""The files of an evaluation directory that programs read back, typed: `EvalRow` (a line of
`episodes.jsonl`) and `EvalManifest` (`eval.json`), each read through one function that
upgrades what older versions of mhrc wrote.

A field added to a row or to the identity after rows were written has, as its default, the
meaning a file without it had (`OLD_MEANING`, `EvalIdentity`'s defaults; a row without a team ran
the paper's, as many of Alice, Bob and David as its `robots`): `read_row` fills it in once, on
read, so summaries never guess. The team's work (mhrc.analysis.teamwork: per-robot messages and
moves, communication steps, redundant actions) is, like the diagnostics, unknown in older rows. A row's diagnostics (`diag_*`) are the exception: a row
written before them does not know them, and stays without them (unknown, never zero). In
memory, summaries take a row as its `record()`, the JSON object the file holds, upgraded.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import structlog
from pydantic import BaseModel, ConfigDict, ValidationError

from mhrc.analysis.metrics import UNRECORDED
from mhrc.core.upgrade import paper_team
from mhrc.eval.spec import EvalIdentity, EvalSpec
from mhrc.run.config import ConfigError

log = structlog.get_logger("mhrc.eval.records")

Row = dict[str, Any]  # a row as summaries take it: EvalRow.record()

# what a row written before a setting field existed ran with (noise: see old_noise)
OLD_MEANING: dict[str, Any] = {
    "fidelity": UNRECORDED,
    "history_cap": None,
    "horizon": None,
    "mode": "free",
    "schedule": "lockstep",
    "scenario": None,
    "prompts": None,
    "base_url": None,
}


def old_noise(aids: Any) -> str:
    """The motion noise of a row older than the field: the calibration, or none under exact_motion."""
    return "off" if "exact_motion" in (aids or ()) else "on"


class EvalRow(BaseModel):
    """One episode's row: the evaluation's settings, the episode's metrics
    (`mhrc.analysis.metrics.EpisodeMetrics`), where it ran, and its diagnostics
    (`mhrc.analysis.diagnostics.Diagnostics`, prefixed `diag_`; None: written before they existed).
    Fields a newer mhrc adds are kept as they are."""

    model_config = ConfigDict(extra="allow")

    key: str
    method: str
    ablation: str
    repeat: int = 0
    trial: int = 0
    # the metrics, in EpisodeMetrics' order
    task: str
    scene: str
    seed: int
    n_objects: int
    robots: list[str]
    reason: str
    success: bool
    placed: int
    total: int
    partial_success: float
    temporal_steps: int
    action_steps: int
    action_steps_per_robot: dict[str, int]
    failed_actions: dict[str, int] = {}
    messages: int = 0
    llm_calls: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    wall_time: float = 0.0
    lower_bound: int | None = None
    parse_failures: int = 0
    llm_unreachable: int = 0
    rejected_actions: int = 0
    valid: bool = True
    invalid_reason: str | None = None
    invalid_code: str | None = None
    fidelity: str = UNRECORDED
    noise: str = "on"
    noise_rates: dict[str, float] = {}
    horizon: int | None = None
    scheduler: str = "lockstep"
    makespan: float = 0.0
    busy: dict[str, float] = {}
    idle: dict[str, float] = {}
    actions_per_robot: dict[str, int] = {}
    active_ticks: int | None = None
    recovery: list[dict[str, Any]] = []
    recovery_ticks: float | None = None
    unrecovered: int | None = None
    team: str = "paper"  # the team: its name, TeamSpec.digest() and each robot's kind (upgrade_row: the paper's)
    team_digest: str = ""
    team_kinds: dict[str, str] = {}
    messages_per_robot: dict[str, int] = {}  # the team's work (mhrc.analysis.teamwork); absent: unknown
    moves_per_robot: dict[str, int] = {}
    communication_steps: int = 0
    redundant_navigations: int = 0
    redundant_picks: int = 0
    redundant_per_robot: dict[str, int] = {}
    # the evaluation's settings
    aids: list[str] = []
    history_cap: int | None = None
    mode: str = "free"
    max_tokens: int | None = None
    llm_seed: int | None = None
    schedule: str = "lockstep"
    time_scale: float = 0.0
    scenario: str | None = None
    scenario_sha256: str | None = None
    prompts: str | None = None
    base_url: str | None = None
    # where it ran
    worker: str = ""
    trace: str | None = None
    # the diagnostics, in Diagnostics' order
    diag_llm_steps: int | None = None
    diag_parse_failures: int | None = None
    diag_llm_unreachable: int | None = None
    diag_hallucinations: int | None = None
    diag_hallucinated_names: dict[str, int] | None = None
    diag_not_capable: int | None = None
    diag_rejected: int | None = None
    diag_rejected_by_reason: dict[str, int] | None = None
    diag_failed: int | None = None
    diag_failed_by_code: dict[str, int] | None = None
    diag_failed_by_skill: dict[str, dict[str, int]] | None = None
    diag_repeated_failures: int | None = None
    diag_waits: int | None = None
    diag_waits_with_pending: int | None = None
    diag_messages_sent: int | None = None
    diag_messages_read: int | None = None
    diag_steps_above_bound: int | None = None

    def record(self) -> Row:
        """The row as its file holds it (JSON types), with the fields it was written with, upgraded:
        what summaries take. A field it never had (its diagnostics, before they existed) stays absent."""
        return self.model_dump(mode="json", exclude_unset=True)

    def line(self) -> str:
        """The row's line of episodes.jsonl."""
        return json.dumps(self.record()) + "\n"


def upgrade_row(raw: dict[str, Any]) -> EvalRow:
    """A row as any version of mhrc wrote it, with the old meaning of every setting field it lacks:
    the one place old rows are upgraded. Raises ValidationError."""
    values = dict(raw)
    for name, old in OLD_MEANING.items():
        values.setdefault(name, old)
    if values.get("noise") is None:  # older than the field
        values["noise"] = old_noise(values.get("aids"))
    if values.get("team") is None:  # older than teams: the paper's, as many of its robots as the row ran
        team = paper_team(values.get("robots"))
        values.update(team=team.name, team_digest=team.digest, team_kinds=dict(team.kinds))
    return EvalRow.model_validate(values)


def read_rows(path: Path) -> list[Row]:
    """The rows of an episodes.jsonl, upgraded (`upgrade_row`); a torn last line, from an
    interrupted write, is skipped. A line that is no row is a ConfigError naming the file and line."""
    if not path.exists():
        return []
    rows = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines()):
        if not line.strip():
            continue
        try:
            raw = json.loads(line)
        except json.JSONDecodeError:
            log.warning("skipping a torn line of episodes.jsonl (an interrupted write)", line=i + 1)
            continue
        try:
            rows.append(upgrade_row(raw).record())
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            raise ConfigError(f"{path}, line {i + 1}: not an episode row ({where}: {err['msg']})") from None
    return rows


def merge_runs(dirs: list[Path]) -> list[Row]:
    """Every episode row of several evaluation directories (for `mhrc report`)."""
    rows = []
    for d in dirs:
        path = d / "episodes.jsonl"
        if not path.exists():
            raise ConfigError(f"{d}: no episodes.jsonl here; is it an `mhrc eval --out` directory?")
        rows += read_rows(path)
    return rows


class EvalManifest(BaseModel):
    """eval.json: the evaluation's identity, which --resume checks, and its spec."""

    identity: EvalIdentity
    spec: EvalSpec | None = None  # None: a manifest whose spec this version cannot read (its identity still counts)

    def text(self) -> str:
        return json.dumps(self.model_dump(mode="json"), indent=2) + "\n"


def read_manifest(path: Path) -> EvalManifest:
    """DIR/eval.json, upgraded: identity fields it lacks get their old meaning (EvalIdentity's
    defaults); a spec this version cannot read is left out. ConfigError naming --out otherwise."""
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        identity = EvalIdentity.model_validate(raw.get("identity") or {})
    except (OSError, ValueError, AttributeError) as exc:
        why = exc.errors()[0]["msg"] if isinstance(exc, ValidationError) else str(exc)
        raise ConfigError(
            f"--out: {path} is not the manifest of an mhrc evaluation ({why}); choose another --out"
        ) from None
    try:
        spec = EvalSpec.model_validate(raw.get("spec"))
    except ValidationError:
        spec = None
    return EvalManifest(identity=identity, spec=spec)
