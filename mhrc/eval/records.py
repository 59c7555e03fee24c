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

A directory may come from someone else, so nothing in it is trusted: a row's values have ranges
(a strict boolean success, PS in [0, 1], counts that are non-negative JSON integers), its key is
its episode's and of the manifest's grid, once, its trace that key's file in traces/; the
manifest has no unknown field and a spec that makes its identity. Any other line is a
ConfigError naming the file and line, before anything is counted or written.
"""

from __future__ import annotations

import json
from collections.abc import Collection
from pathlib import Path
from typing import Annotated, Any

import structlog
from pydantic import BaseModel, ConfigDict, Field, StrictBool, ValidationError, model_validator

from mhrc.analysis.metrics import UNRECORDED
from mhrc.core.upgrade import paper_team
from mhrc.eval.directory import read_bytes
from mhrc.eval.spec import MAX_COUNT, EvalIdentity, EvalSpec, bounded, episode_key
from mhrc.run.config import ConfigError

log = structlog.get_logger("mhrc.eval.records")

Row = dict[str, Any]  # a row as summaries take it: EvalRow.record()

# a row's values with their ranges: a count is a non-negative JSON integer (never a string, a float
# or a bool), a rate lies in [0, 1], an amount (seconds, a scale) is finite and non-negative
Count = Annotated[int, Field(strict=True, ge=0, le=MAX_COUNT)]
Seed = Annotated[int, Field(strict=True, ge=-MAX_COUNT, le=MAX_COUNT)]
Rate = Annotated[float, Field(strict=True, ge=0.0, le=1.0, allow_inf_nan=False)]
Amount = Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)]
NAME = r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}"  # a task, scene or team as a part of a key (and of a file name)
Name = Annotated[str, Field(pattern=f"^{NAME}$")]

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

    key: str = Field(max_length=512)
    method: str
    ablation: str
    repeat: Count = 0
    trial: Count = 0
    # the metrics, in EpisodeMetrics' order
    task: Name
    scene: Name
    seed: Count
    n_objects: Count
    robots: list[str]
    reason: str
    success: StrictBool
    placed: Count
    total: Count
    partial_success: Rate
    temporal_steps: Count
    action_steps: Count
    action_steps_per_robot: dict[str, Count]
    failed_actions: dict[str, Count] = {}
    messages: Count = 0
    llm_calls: Count = 0
    prompt_tokens: Count = 0
    completion_tokens: Count = 0
    wall_time: Amount = 0.0
    lower_bound: Count | None = None
    parse_failures: Count = 0
    llm_unreachable: Count = 0
    rejected_actions: Count = 0
    valid: StrictBool = True
    invalid_reason: str | None = None
    invalid_code: str | None = None
    fidelity: str = UNRECORDED
    noise: str = "on"
    noise_rates: dict[str, Amount] = {}
    horizon: Count | None = None
    scheduler: str = "lockstep"
    makespan: Amount = 0.0
    busy: dict[str, Amount] = {}
    idle: dict[str, Amount] = {}
    actions_per_robot: dict[str, Count] = {}
    active_ticks: Count | None = None
    recovery: list[dict[str, Any]] = []
    recovery_ticks: Amount | None = None
    unrecovered: Count | None = None
    team: Name = "paper"  # the team: its name, TeamSpec.digest() and each robot's kind (upgrade_row: the paper's)
    team_digest: str = ""
    team_kinds: dict[str, str] = {}
    messages_per_robot: dict[str, Count] = {}  # the team's work (mhrc.analysis.teamwork); absent: unknown
    moves_per_robot: dict[str, Count] = {}
    communication_steps: Count = 0
    redundant_navigations: Count = 0
    redundant_picks: Count = 0
    redundant_per_robot: dict[str, Count] = {}
    # the evaluation's settings
    aids: list[str] = []
    history_cap: Count | None = None
    mode: str = "free"
    max_tokens: Count | None = None
    llm_seed: Seed | None = None
    schedule: str = "lockstep"
    time_scale: Amount = 0.0
    scenario: str | None = None
    scenario_sha256: str | None = None
    prompts: str | None = None
    base_url: str | None = None
    # where it ran
    worker: str = ""
    trace: str | None = None
    # the diagnostics, in Diagnostics' order
    diag_llm_steps: Count | None = None
    diag_parse_failures: Count | None = None
    diag_llm_unreachable: Count | None = None
    diag_hallucinations: Count | None = None
    diag_hallucinated_names: dict[str, Count] | None = None
    diag_not_capable: Count | None = None
    diag_rejected: Count | None = None
    diag_rejected_by_reason: dict[str, Count] | None = None
    diag_failed: Count | None = None
    diag_failed_by_code: dict[str, Count] | None = None
    diag_failed_by_skill: dict[str, dict[str, Count]] | None = None
    diag_repeated_failures: Count | None = None
    diag_waits: Count | None = None
    diag_waits_with_pending: Count | None = None
    diag_messages_sent: Count | None = None
    diag_messages_read: Count | None = None
    diag_steps_above_bound: Count | None = None

    @model_validator(mode="after")
    def _consistent(self) -> EvalRow:
        """The key is the one its task, scene, objects, seed and team make; the trace, if any, is that
        key's file in traces/ (a path anywhere else, or a URL, is no trace of this directory)."""
        key = episode_key(None if self.team == "paper" else self.team, self.task, self.scene, self.n_objects, self.seed)
        if self.key != key:
            raise ValueError(f"key {self.key!r} is not its episode's ({key!r})")
        if self.trace is not None and self.trace != trace_of(key):
            raise ValueError(f"trace {self.trace!r} is not its episode's file ({trace_of(key)!r})")
        if self.placed > self.total:
            raise ValueError(f"placed {self.placed} of {self.total} objects")
        return self

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


def trace_of(key: str) -> str:
    """The trace of episode `key`, relative to its evaluation directory."""
    return f"traces/{key.replace('/', '_')}.jsonl"


def _lines(path: Path) -> tuple[list[tuple[int, str]], bool]:
    """The non-blank lines of a file of the directory (read without following a symlink), numbered
    from 1, and whether the file ends with a newline (a last line without one may be torn); bytes
    that are not UTF-8 are a ConfigError naming the line."""
    data = read_bytes(path)
    if data is None:
        return [], True
    out = []
    for i, raw in enumerate(data.split(b"\n")):
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{path}, line {i + 1}: not UTF-8 text (byte {exc.start + 1})") from None
        if line.strip():
            out.append((i + 1, line))
    return out, data.endswith(b"\n")


def _json(path: Path, n: int, line: str) -> Any:
    """One line's JSON value, or ConfigError naming the line (nested too deeply, not JSON)."""
    try:
        return json.loads(line)
    except RecursionError:
        raise ConfigError(f"{path}, line {n}: nested too deeply to be an episode row") from None


def _first_error(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"])
    return f"{where}: {err['msg']}" if where else str(err["msg"])


def read_rows(path: Path, grid: Collection[str] | None = None) -> list[Row]:
    """The rows of an episodes.jsonl, validated and upgraded (`upgrade_row`). A torn last line
    (no newline after it: an interrupted write) is skipped; any other line that is no row (not
    UTF-8, not JSON, a value out of its range, a key twice, or, given `grid`, a key the grid does
    not hold) is a ConfigError naming the file and the line."""
    lines, data_ends_whole = _lines(path)
    rows: list[Row] = []
    seen: dict[str, int] = {}
    for k, (n, line) in enumerate(lines):
        try:
            raw = _json(path, n, line)
        except json.JSONDecodeError:
            if k == len(lines) - 1 and not data_ends_whole:
                log.warning("skipping a torn line of episodes.jsonl (an interrupted write)", line=n)
                continue
            raise ConfigError(f"{path}, line {n}: not JSON") from None
        if not isinstance(raw, dict):
            raise ConfigError(f"{path}, line {n}: not an episode row (a JSON object)")
        try:
            row = upgrade_row(raw)
        except ValidationError as exc:
            raise ConfigError(f"{path}, line {n}: not an episode row ({_first_error(exc)})") from None
        if row.key in seen:
            raise ConfigError(f"{path}, line {n}: episode {row.key} again (line {seen[row.key]})")
        if grid is not None and row.key not in grid:
            raise ConfigError(f"{path}, line {n}: episode {row.key} is not in this evaluation's grid (eval.json)")
        seen[row.key] = n
        rows.append(row.record())
    return rows


def read_dir(d: Path) -> list[Row]:
    """The rows of evaluation directory `d`, each checked against its manifest's grid (for `mhrc
    report`): ConfigError for a directory without either, or a row outside the grid."""
    path = d / "episodes.jsonl"
    if read_bytes(path) is None:
        raise ConfigError(f"{d}: no episodes.jsonl here; is it an `mhrc eval --out` directory?")
    manifest = read_manifest(d / "eval.json", option=str(d))
    grid = manifest.spec.keys() if manifest.spec is not None else None
    rows = read_rows(path, grid)
    for r in rows:
        if (r["method"], r["ablation"]) != (manifest.identity.method, manifest.identity.ablation):
            raise ConfigError(
                f"{path}: episode {r['key']} ran {r['method']}, ablation {r['ablation']}, not the evaluation's"
            )
        if r.get("horizon") is not None and r["horizon"] != manifest.identity.horizon:
            raise ConfigError(
                f"{path}: episode {r['key']} ran horizon {r['horizon']}, not the evaluation's {manifest.identity.horizon}"
            )
    return rows


def merge_runs(dirs: list[Path]) -> list[Row]:
    """Every episode row of several evaluation directories (for `mhrc report`), each read by `read_dir`."""
    return [r for d in dirs for r in read_dir(d)]


class EvalManifest(BaseModel):
    """eval.json: the evaluation's identity, which --resume checks, and its spec (its grid and every
    setting, which --resume runs)."""

    model_config = ConfigDict(extra="forbid")

    identity: EvalIdentity
    spec: EvalSpec | None = None  # None: a manifest written before the spec was kept (its identity still counts)

    def text(self) -> str:
        return json.dumps(self.model_dump(mode="json"), indent=2) + "\n"


def read_manifest(path: Path, *, option: str = "--out") -> EvalManifest:
    """DIR/eval.json, validated: identity fields it lacks get their old meaning (EvalIdentity's
    defaults); an unknown field, a value of the wrong type or out of range, a spec that does not
    make its identity, is a ConfigError naming `option` and the file."""

    def refused(why: str) -> ConfigError:
        return ConfigError(f"{option}: {path} is not the manifest of an mhrc evaluation ({why})")

    try:
        data = read_bytes(path)
    except OSError as exc:
        raise refused(exc.strerror or str(exc)) from None
    if data is None:
        raise refused("no such file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise refused(f"not UTF-8 text at byte {exc.start + 1}") from None
    try:
        json.loads(text)  # the standard parser first: nesting it cannot take is a RecursionError here
        manifest = EvalManifest.model_validate_json(text, strict=True)
    except RecursionError:
        raise refused("nested too deeply") from None
    except json.JSONDecodeError as exc:
        raise refused(f"not JSON: {exc.msg}, line {exc.lineno}") from None
    except ValidationError as exc:
        raise refused(_first_error(exc)) from None
    spec = manifest.spec
    if spec is not None:
        if why := bounded(spec):
            raise refused(f"spec.{why}")
        try:
            made = spec.identity(manifest.identity.scenario)
        except (ConfigError, ValueError, OSError) as exc:
            raise refused(f"spec: {exc}") from None
        stored = manifest.identity
        if differs := [f for f in sorted(stored.model_fields_set) if getattr(made, f) != getattr(stored, f)]:
            raise refused(f"its spec does not make its identity: {', '.join(differs)}")
    return manifest
