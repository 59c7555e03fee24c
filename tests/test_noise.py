"""The motion noise: mhrc's calibration (not the paper's), recorded in every trace header and
every result row, and `--noise off` for a world without it: bases stop exactly and releases
do not slip, recorded as a setting of its own that summaries never average with the default.
Real episodes: the heuristic team in real PyBullet, tick by tick (test_table3.play), and on
real Zenoh buses on loopback through `mhrc up`, `mhrc world` and `mhrc eval`."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from test_metrics import _put  # a hand-built trace line, with the protocol's required fields
from test_table3 import play

from mhrc.analysis.metrics import from_trace
from mhrc.core.fidelity import CALIBRATION, NOISELESS, recorded_noise
from mhrc.core.protocol import EpisodeStarted, Move, Navigate, OutcomeCode, decode_event
from mhrc.core.records import messages, read_records
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.records import upgrade_row
from mhrc.eval.report import summary_markdown
from mhrc.eval.rows import setting_label, setting_of
from mhrc.eval.spec import episode_key
from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.world.sim import Sim

RATES = {"navigation_slip": 0.03, "navigation_sigma": 0.015, "release_slip": 0.1, "release_sigma": 0.003}
# seeded episodes whose default run has a navigation off target and releases that slip (2-4 cm)
NOISY = [("make_sandwich", "kitchen", 6, 7), ("make_sandwich", "bathroom", 5, 1)]


def _started(trace: Path) -> EpisodeStarted:
    return messages(read_records(trace), EpisodeStarted)[0]


def _rows(out: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]


def test_the_calibration_is_the_recorded_default_and_off_is_none() -> None:
    assert CALIBRATION.model_dump() == {"setting": "on", **RATES}
    assert NOISELESS.model_dump() == {"setting": "off", **dict.fromkeys(RATES, 0.0)}
    assert EpisodeConfig.build().noise == "on" and EpisodeConfig.build(noise="off").noise == "off"
    with Sim(seed=0, n_objects=3) as sim:
        assert sim.noise == CALIBRATION
    with Sim(seed=0, n_objects=3, noise="off") as sim:
        assert sim.noise == NOISELESS
    with Sim(seed=0, n_objects=3, aids=("exact_motion",)) as sim:  # the aid draws no noise either: recorded as off
        assert sim.noise == NOISELESS


def _run(key: tuple[str, str, int, int], noise: str) -> tuple[list[Any], list[tuple[float, float]]]:
    """The heuristic team's steps on one seeded episode, and the error of every release (where
    the world let go of an object, off the tool's spot), seen by a spy on the real release."""
    task, scene, n, seed = key
    with Sim(task=task, scene=scene, seed=seed, n_objects=n, noise=noise) as sim:
        errors: list[tuple[float, float]] = []
        release = sim.world.release

        def spy(
            r: Any,
            obj: Any,
            spot: Any,
            yaw: float,
            location: str | None = None,
            error: tuple[float, float] = (0.0, 0.0),
        ) -> None:
            errors.append(error)
            release(r, obj, spot, yaw, location, error)

        sim.world.release = spy  # type: ignore[method-assign]
        ok, steps = play(sim)
        assert ok, key
        return steps, errors


def test_noise_off_stops_exactly_and_nothing_slips_where_the_default_has_both() -> None:
    noisy = [_run(key, "on") for key in NOISY]
    off_target = [s for steps, _ in noisy for s in steps if s.outcome.code == OutcomeCode.OFF_TARGET]
    slips = [e for _, errors in noisy for e in errors if math.hypot(*e) >= 0.02]
    assert off_target and slips, "these seeds show both kinds of noise by default"
    for key in NOISY:
        steps, errors = _run(key, "off")
        assert not [s for s in steps if s.outcome.code == OutcomeCode.OFF_TARGET], key
        stops = [s for s in steps if isinstance(s.action, Navigate) and s.outcome.succeeded]
        assert stops and all(float(s.outcome.details["distance"]) == 0.0 for s in stops), (
            key
        )  # exactly on the stand pose
        for s in (s for s in steps if isinstance(s.action, Move) and s.outcome.succeeded):
            assert (s.outcome.details["dx"], s.outcome.details["dy"]) == pytest.approx(
                (s.action.dx, s.action.dy), abs=1e-9
            ), key
        assert errors and all(e == (0.0, 0.0) for e in errors), (
            key
        )  # every release falls from exactly where the tool let go


def test_a_real_episode_records_the_rates_in_its_trace_and_row_and_noise_off_is_a_setting_of_its_own(
    tmp_path: Path,
) -> None:
    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), horizon=3)
    default = asyncio.run(evaluate(spec, tmp_path / "on", workers=1))
    # --noise off through the command line: mhrc eval's option, its workers' worlds
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "eval",
        "--tasks",
        "pack_objects",
        "--scenes",
        "kitchen",
        "--objects",
        "3",
        "--horizon",
        "3",
        "--workers",
        "1",
        "--noise",
        "off",
        "--out",
        str(tmp_path / "off"),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "fidelity paper, noise off" in out.stderr
    noiseless = _rows(tmp_path / "off")
    for rows, where, noise, rates in (
        ([r.flat() for r in default], tmp_path / "on", "on", RATES),
        (noiseless, tmp_path / "off", "off", dict.fromkeys(RATES, 0.0)),
    ):
        (row,) = rows
        started = _started(where / str(row["trace"]))
        assert started.noise.model_dump() == {"setting": noise, **rates}
        assert (row["noise"], row["noise_rates"]) == (noise, rates)
    noiseless = [upgrade_row(r) for r in noiseless]
    on, off = setting_of(default[0]), setting_of(noiseless[0])
    assert on != off and setting_label(on) == "heuristic · ablation none · paper · horizon 3"
    assert setting_label(off) == "heuristic · ablation none · paper · noise off · horizon 3"
    summary = summary_markdown(default + noiseless)  # a section each, never averaged together
    assert (
        "### heuristic · ablation none · paper · horizon 3\n" in summary
        and "### heuristic · ablation none · paper · noise off · horizon 3\n" in summary
    )
    assert json.loads((tmp_path / "on" / "eval.json").read_text())["identity"]["noise"] == "on"


def test_mhrc_up_and_its_world_process_run_without_noise_when_asked(tmp_path: Path) -> None:
    """`mhrc up --processes --noise off` hands the setting to the `mhrc world` process it starts."""
    trace = tmp_path / "t.jsonl"
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "up",
        "--processes",
        "--insecure",
        "--noise",
        "off",
        "--objects",
        "3",
        "--horizon",
        "2",
        "--trace",
        str(trace),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert _started(trace).noise == NOISELESS
    assert "fidelity paper, noise off" in out.stdout


def test_a_trace_or_row_from_before_the_field_reads_as_the_calibration() -> None:
    old = {
        "kind": "episode_started",
        "run": "r",
        "task": "pack_objects",
        "scene": "kitchen",
        "seed": 0,
        "n_objects": 3,
        "robots": ["alice"],
        "horizon": 5,
        "fidelity": "paper",
        "aids": [],
    }
    event = decode_event(json.dumps(old))
    assert isinstance(event, EpisodeStarted) and event.noise == CALIBRATION
    assert recorded_noise(old) == CALIBRATION
    assert (
        recorded_noise({**old, "fidelity": "aids:exact_motion", "aids": ["exact_motion"]}) == NOISELESS
    )  # that aid never drew noise
    done = {
        "kind": "episode_done",
        "run": "r",
        "reason": "horizon",
        "metrics": {"success": False, "placed": 0, "total": 3, "partial_success": 0.0},
    }
    line = {k: v for k, v in old.items() if k != "kind"}
    end = {k: v for k, v in done.items() if k != "kind"}
    m = from_trace(records([_put("episode_started", **line), _put("episode_done", **end)]))
    assert (m.noise, m.noise_rates) == ("on", RATES)
    metrics = {k: v for k, v in m.as_dict().items() if k not in ("noise", "horizon")}  # a row older than the field
    row = {
        **metrics,
        "key": episode_key(None, m.task, m.scene, m.n_objects, m.seed),
        "method": "heuristic",
        "ablation": "none",
        "fidelity": "paper",
        "aids": [],
        "schedule": "sequential",
    }
    assert (
        setting_of(upgrade_row(row)) == setting_of(upgrade_row({**row, "noise": "on"}))
        and setting_label(setting_of(upgrade_row(row))) == "heuristic · ablation none · paper"
    )
    assert setting_of(upgrade_row({**row, "fidelity": "aids:exact_motion", "aids": ["exact_motion"]}))[3] == "off"


@pytest.mark.parametrize("command", ["up", "world", "eval"])
def test_a_bad_noise_value_fails_before_anything_starts_naming_the_option(tmp_path: Path, command: str) -> None:
    where = (
        ["--out", str(tmp_path / "x")]
        if command == "eval"
        else ["--trace", str(tmp_path / "x" / "t.jsonl"), "--insecure"]
    )
    out = subprocess.run(
        [sys.executable, "-m", "mhrc", command, "--noise", "loud", *where], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2 and "Invalid value for '--noise': 'loud' is not one of 'on', 'off'" in out.stderr, (
        out.stderr
    )
    assert not (tmp_path / "x").exists()


def test_a_bad_noise_value_through_the_api_names_the_option() -> None:
    with pytest.raises(
        ConfigError,
        match=r"^--noise: unknown setting 'loud'; use on \(the calibrated motion noise, the default\) or off \(none\)$",
    ):
        EpisodeConfig.build(noise="loud")
    with pytest.raises(ConfigError, match="^--noise: unknown setting 'loud'"):
        EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), noise="loud").validate()
