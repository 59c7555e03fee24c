"""The files of an evaluation directory that programs read back, typed: `EvalRow` (a line of
`episodes.jsonl`) and `EvalManifest` (`eval.json`), each read through one function that
upgrades what older versions of mhrc wrote.

A row is composed, never restated: the evaluation's `settings`, the episode's `metrics` (the one
`mhrc.analysis.metrics.EpisodeMetrics`), its `diagnostics` (`mhrc.analysis.diagnostics.Diagnostics`;
None: written before they existed), the `worker` that ran it and its `trace`. Only the file is
flat: a line of episodes.jsonl holds every field of these at its top level (the diagnostics
prefixed `diag_`), in the order `FLAT_ORDER` gives, and `EvalRow.flat` and `from_flat` are the one
place a row is flattened and put together again. A metric added to EpisodeMetrics reaches the file
and comes back without being declared anywhere else.

A field added to a row or to the identity after rows were written has, as its default, the
meaning a file without it had (`OLD_MEANING`, `EvalIdentity`'s defaults; a row without a team ran
the paper's, as many of Alice, Bob and David as its `robots`): `upgrade_row` fills it in once, on
read, so summaries never guess. A field a row was written without stays unset in its model
(`model_fields_set`), so the row is written back as it was read; the team's work
(mhrc.analysis.teamwork) is, like the diagnostics, unknown in a row that lacks it (mhrc.eval.means).

A directory may come from someone else, so nothing in it is trusted: a row's values have ranges
(mhrc.analysis.values: a strict boolean success, PS in [0, 1], counts that are non-negative JSON
integers), its key is its episode's and of the manifest's grid, once, its trace that key's file in
traces/; the manifest has no unknown field and a spec that makes its identity. Any other line is a
ConfigError naming the file and line, before anything is counted or written.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from mhrc.analysis.diagnostics import Diagnostics
from mhrc.analysis.metrics import UNRECORDED, EpisodeMetrics
from mhrc.analysis.values import Amount, Count, Seed
from mhrc.core.logs import get_logger
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.upgrade import paper_team
from mhrc.eval.directory import read_bytes
from mhrc.eval.spec import EvalIdentity, EvalSpec, bounded, episode_key
from mhrc.run.config import ConfigError

log = get_logger("mhrc.eval.records")

Flat = dict[str, object]  # a row as a line of episodes.jsonl holds it: JSON values by column

# what a row written before a setting field existed ran with (noise: see old_noise)
OLD_MEANING: dict[str, object] = {
    "fidelity": UNRECORDED,
    "history_cap": None,
    "horizon": None,
    "mode": "free",
    "schedule": "lockstep",
    "scenario": None,
    "prompts": None,
    "base_url": None,
}


def old_noise(aids: object) -> str:
    """The motion noise of a row older than the field: the calibration, or none under exact_motion."""
    return "off" if "exact_motion" in (aids if isinstance(aids, (list, tuple)) else ()) else "on"


class Settings(BaseModel):
    """The evaluation's settings an episode ran with (what its row does not measure)."""

    method: str
    ablation: str
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
    # how the team decided (mhrc.agents.protocols): written only when not the paper's, so that the paper's rows
    # stay as they were; a row without it ran the paper's; a name no protocol is registered under is no row
    protocol: str = DEFAULT_PROTOCOL

    @field_validator("protocol")
    @classmethod
    def _protocol(cls, v: str) -> str:
        from mhrc.agents.protocols import PROTOCOLS

        if v not in PROTOCOLS:
            raise ValueError(f"unknown protocol {v!r} (the protocols: {', '.join(PROTOCOLS)})")
        return v


DIAG = "diag_"  # the prefix of the diagnostics' columns in episodes.jsonl
PARTS = ("settings", "metrics", "diagnostics")  # the submodels; never a column of the file


class EvalRow(BaseModel):
    """One episode's row: its key (and repeat and trial), the evaluation's settings, the episode's
    metrics and diagnostics, and where it ran. Columns a newer mhrc adds are kept as they are
    (`model_extra`), and written back after the others."""

    model_config = ConfigDict(extra="allow")

    key: str = Field(max_length=512)
    repeat: Count = 0
    trial: Count = 0
    settings: Settings
    metrics: EpisodeMetrics
    diagnostics: Diagnostics | None = None  # None: written before diagnostics existed (unknown, never zero)
    worker: str = ""
    trace: str | None = None

    @model_validator(mode="after")
    def _consistent(self) -> EvalRow:
        """The key is the one its task, scene, objects, seed and team make; the trace, if any, is that
        key's file in traces/ (a path anywhere else, or a URL, is no trace of this directory)."""
        m = self.metrics
        key = episode_key(
            None if m.team == "paper" else m.team, m.task, m.scene, m.n_objects, m.seed, self.settings.protocol
        )
        if self.key != key:
            raise ValueError(f"key {self.key!r} is not its episode's ({key!r})")
        if self.trace is not None and self.trace != trace_of(key):
            raise ValueError(f"trace {self.trace!r} is not its episode's file ({trace_of(key)!r})")
        if m.placed > m.total:
            raise ValueError(f"placed {m.placed} of {m.total} objects")
        return self

    @property
    def valid(self) -> bool:
        return self.metrics.valid

    def flat(self) -> Flat:
        """The row as its line of episodes.jsonl holds it (JSON values, `FLAT_ORDER`), with the
        fields it was written with, upgraded; a field it never had (its diagnostics, before they
        existed) stays absent."""
        parts: dict[str, Flat] = {
            "row": self.model_dump(mode="json", exclude_unset=True, exclude=set(PARTS)),
            "settings": self.settings.model_dump(mode="json", exclude_unset=True),
            "metrics": self.metrics.model_dump(mode="json", exclude_unset=True),
            "diagnostics": {}
            if self.diagnostics is None
            else {DIAG + k: v for k, v in self.diagnostics.model_dump(mode="json", exclude_unset=True).items()},
        }
        out: Flat = {}
        for part, names in FLAT_ORDER:
            mine = parts[part]
            out.update((k, mine[k]) for k in (names or tuple(mine)) if k in mine)
        out.update(self.model_extra or {})
        return out

    def line(self) -> str:
        """The row's line of episodes.jsonl."""
        return json.dumps(self.flat()) + "\n"


# the order of a line's columns: the key, the method and ablation, repeat and trial, the metrics,
# the other settings, where it ran, the diagnostics (each part's fields in its model's order; None: all)
_LEAD = ("method", "ablation")
FLAT_ORDER: tuple[tuple[str, tuple[str, ...] | None], ...] = (
    ("row", ("key",)),
    ("settings", _LEAD),
    ("row", ("repeat", "trial")),
    ("metrics", None),
    ("settings", tuple(f for f in Settings.model_fields if f not in _LEAD)),
    ("row", ("worker", "trace")),
    ("diagnostics", None),
)


def from_flat(values: Mapping[str, object]) -> EvalRow:
    """The row a line of episodes.jsonl holds (its columns put back into their parts); raises
    ValidationError for a value out of its range, ValueError for a column named as a part."""
    if clash := sorted(set(values) & set(PARTS)):
        raise ValueError(f"{clash[0]}: no column of a row")
    part_of = {
        **{f: "settings" for f in Settings.model_fields},
        **{f: "metrics" for f in EpisodeMetrics.model_fields},
        **{DIAG + f: "diagnostics" for f in Diagnostics.model_fields},
    }
    nested: dict[str, dict[str, object]] = {part: {} for part in PARTS}
    top: dict[str, object] = {}
    for k, v in values.items():
        part = part_of.get(k)
        if part == "diagnostics":
            nested[part][k.removeprefix(DIAG)] = v
        elif part is not None:
            nested[part][k] = v
        else:
            top[k] = v  # the row's own fields, and columns a newer mhrc added
    return EvalRow.model_validate({**top, **nested, "diagnostics": nested["diagnostics"] or None})


def upgrade_row(raw: Mapping[str, object]) -> EvalRow:
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
    return from_flat(values)


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
    """The first error, located by the file's column (a row's part is no column of it)."""
    err = exc.errors()[0]
    loc = list(err["loc"])
    if len(loc) > 1 and loc[0] in PARTS:
        loc = [(DIAG if loc[0] == "diagnostics" else "") + str(loc[1]), *loc[2:]]
    where = ".".join(str(p) for p in loc)
    return f"{where}: {err['msg']}" if where else str(err["msg"])


def read_rows(path: Path, grid: Collection[str] | None = None) -> list[EvalRow]:
    """The rows of an episodes.jsonl, validated and upgraded (`upgrade_row`). A torn last line
    (no newline after it: an interrupted write) is skipped; any other line that is no row (not
    UTF-8, not JSON, a value out of its range, a key twice, or, given `grid`, a key the grid does
    not hold) is a ConfigError naming the file and the line."""
    lines, data_ends_whole = _lines(path)
    rows: list[EvalRow] = []
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
        except ValueError as exc:  # a ValidationError, or a column named as a part of the row
            why = _first_error(exc) if isinstance(exc, ValidationError) else str(exc)
            raise ConfigError(f"{path}, line {n}: not an episode row ({why})") from None
        if row.key in seen:
            raise ConfigError(f"{path}, line {n}: episode {row.key} again (line {seen[row.key]})")
        if grid is not None and row.key not in grid:
            raise ConfigError(f"{path}, line {n}: episode {row.key} is not in this evaluation's grid (eval.json)")
        seen[row.key] = n
        rows.append(row)
    return rows


def read_dir(d: Path) -> list[EvalRow]:
    """The rows of evaluation directory `d`, each checked against its manifest's grid (for `mhrc
    report`): ConfigError for a directory without either, or a row outside the grid."""
    path = d / "episodes.jsonl"
    if read_bytes(path) is None:
        raise ConfigError(f"{d}: no episodes.jsonl here; is it an `mhrc eval --out` directory?")
    manifest = read_manifest(d / "eval.json", option=str(d))
    grid = manifest.spec.keys() if manifest.spec is not None else None
    rows = read_rows(path, grid)
    for r in rows:
        s, horizon = r.settings, r.metrics.horizon
        if (s.method, s.ablation) != (manifest.identity.method, manifest.identity.ablation):
            raise ConfigError(f"{path}: episode {r.key} ran {s.method}, ablation {s.ablation}, not the evaluation's")
        if s.protocol not in manifest.identity.protocols:
            raise ConfigError(f"{path}: episode {r.key} ran protocol {s.protocol}, not one of the evaluation's")
        if horizon is not None and horizon != manifest.identity.horizon:
            raise ConfigError(
                f"{path}: episode {r.key} ran horizon {horizon}, not the evaluation's {manifest.identity.horizon}"
            )
    return rows


def merge_runs(dirs: list[Path]) -> list[EvalRow]:
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
