"""`mhrc eval --resume`: the evaluation continued is the one its directory holds.

Its grid, horizon and every setting come from DIR/eval.json (`EvalManifest.spec`), never from
the command's defaults: `mhrc eval --resume --out DIR` finishes the interrupted grid and runs
nothing more. An option given beside --resume must say what the manifest says; a different
value (another --tasks, --scenes, --objects, --horizon, model...) is refused, in one line naming
each option with both values, so two grids are never merged into one directory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mhrc.eval.records import read_manifest
from mhrc.eval.spec import EvalSpec, team_identity
from mhrc.run.config import ConfigError

# EvalSpec fields an option of `mhrc eval` sets, by the option's parameter name (the same name)
SPEC_OPTIONS = (
    "tasks",
    "scenes",
    "objects",
    "trials",
    "repeats",
    "teams",
    "protocols",
    "ablation",
    "horizon",
    "aids",
    "noise",
    "schedule",
    "time_scale",
    "events",
    "llm",
    "base_url",
    "llm_timeout",
    "llm_idle_timeout",
    "stream",
    "max_tokens",
    "llm_seed",
    "structured",
    "step_deadline",
    "prompts",
    "history_cap",
)


def _shown(field: str, value: Any) -> str:
    """A spec value as a person gave it on the command line."""
    if field == "teams":
        return ",".join(team_identity(t) for t in value)
    if isinstance(value, tuple):
        return ",".join(map(str, value)) or "(none)"
    return repr(value)


def _option(field: str) -> str:
    if field == "protocols":
        return "--protocol"
    return "--stream/--no-stream" if field == "stream" else "--" + field.replace("_", "-")


def differences(before: EvalSpec, now: EvalSpec, given: set[str]) -> list[str]:
    """Each option in `given` whose value in `now` differs from the evaluation's (`before`), as
    `--horizon was 30, now 50`."""
    out = []
    for field in SPEC_OPTIONS:
        if field not in given:
            continue
        was, new = getattr(before, field), getattr(now, field)
        if field == "teams":
            was, new = [team_identity(t) for t in was], [team_identity(t) for t in new]
            if was == new:
                continue
            out.append(f"--team was {','.join(was)}, now {','.join(new)}")
            continue
        if was != new:
            out.append(f"{_option(field)} was {_shown(field, was)}, now {_shown(field, new)}")
    return out


def resumed_spec(out: Path, now: EvalSpec, given: set[str]) -> EvalSpec:
    """The spec `mhrc eval --resume --out DIR` runs: the one DIR/eval.json holds, when every option
    in `given` (the options the command line set) agrees with it; ConfigError naming each that does
    not. A manifest older than the spec it keeps: the options' spec, which check_out then compares
    with the manifest's identity. No eval.json: `now` (check_out says DIR holds no evaluation)."""
    path = out / "eval.json"
    if not path.is_file() and not path.is_symlink():
        return now
    manifest = read_manifest(path)
    if manifest.spec is None:
        return now
    if diff := differences(manifest.spec, now, given):
        raise ConfigError(f"--resume: {out} holds another evaluation: {'; '.join(diff)}")
    return manifest.spec
