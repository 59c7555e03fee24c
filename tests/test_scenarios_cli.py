"""Shipped scenarios by name (issue 25): `mhrc scenarios` lists and explains them, `--events NAME`
runs one on `up`, `world` and `eval` (an existing file wins), a name that is neither is refused
before anything starts, and the files ship with the package."""

from __future__ import annotations

import hashlib
import json
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.world.scenario import load_scenario, resolve_scenario, shipped_scenarios

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(p.stem for p in (ROOT / "world" / "scenarios").glob("*.json"))


def _errors(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("Error:")]


def test_the_shipped_scenarios_are_the_package_folder() -> None:
    assert SHIPPED and list(shipped_scenarios()) == SHIPPED
    assert {"relocate", "breakdown", "new_target", "close", "busy_house"} <= set(SHIPPED)


def test_the_shipped_files_are_package_data() -> None:
    """A wheel holds only the data files pyproject's package-data names: each shipped scenario must match."""
    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["package-data"]
    globs = data.get("mhrc.world", [])
    for name in SHIPPED:
        assert any(fnmatch(f"scenarios/{name}.json", g) for g in globs), (
            f"scenarios/{name}.json is not in package-data {globs}"
        )


def test_scenarios_lists_each_with_its_events_and_hash() -> None:
    res = CliRunner().invoke(main, ["scenarios"])
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert [line.split()[0] for line in lines] == SHIPPED
    for line, name in zip(lines, SHIPPED):
        path = ROOT / "world" / "scenarios" / f"{name}.json"
        events = json.loads(path.read_text(encoding="utf-8"))
        assert line.split()[-1] == hashlib.sha256(path.read_bytes()).hexdigest()[:12]
        assert ", ".join(f"{e['kind']}@{e['tick']}" for e in events) in line
    busy = next(line for line in lines if line.startswith("busy_house"))
    assert "relocate@6, close@9, breakdown@12, new_target@14" in busy


def test_scenarios_name_prints_every_event_with_what_it_does() -> None:
    res = CliRunner().invoke(main, ["scenarios", "busy_house"])
    assert res.exit_code == 0, res.output
    sha = hashlib.sha256((ROOT / "world/scenarios/busy_house.json").read_bytes()).hexdigest()
    lines = res.stdout.splitlines()
    assert sha in lines[0] and "4 event(s)" in lines[0]
    assert lines[1].startswith("  [0] tick 6: relocate: someone moves a target not yet in place")
    assert lines[2].startswith("  [1] tick 9: close: the container opened most recently closes")
    assert lines[3].startswith("  [2] tick 12: breakdown: david breaks down for 5 tick(s), until tick 17")
    assert lines[4].startswith("  [3] tick 14: new_target: one more object")


def test_scenarios_of_a_file_and_of_an_unknown_name(tmp_path: Path) -> None:
    mine = tmp_path / "mine.json"
    mine.write_text(json.dumps([{"tick": 4, "kind": "relocate", "object": "mug", "to": "sofa"}]), encoding="utf-8")
    res = CliRunner().invoke(main, ["scenarios", str(mine)])
    assert res.exit_code == 0 and "[0] tick 4: relocate: someone moves mug to sofa" in res.stdout
    res = CliRunner().invoke(main, ["scenarios", "nope"])
    assert res.exit_code == 2
    (error,) = _errors(res.stderr)
    assert error.startswith("Error: NAME: nope is neither a file nor a shipped scenario") and all(
        n in error for n in SHIPPED
    )


def test_scenarios_help_says_what_it_lists() -> None:
    res = CliRunner().invoke(main, ["scenarios", "--help"])
    assert res.exit_code == 0 and "shipped scenarios" in res.stdout and "--events NAME" in res.stdout
    assert "scenarios" in CliRunner().invoke(main, ["--help"]).stdout


@pytest.mark.parametrize("command", [["up", "--quiet"], ["world"], ["eval", "--dry-run"]])
def test_an_events_name_that_is_neither_file_nor_shipped_is_refused(
    tmp_path: Path, command: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.iterdir())
    res = CliRunner().invoke(main, [*command, "--events", "relocat"])
    assert res.exit_code == 2, res.output
    (error,) = _errors(res.stderr)
    assert (
        error.startswith("Error: --events: relocat is neither a file nor a shipped scenario")
        and "mhrc scenarios" in error
    )
    assert all(n in error for n in SHIPPED)
    assert set(tmp_path.iterdir()) == before  # nothing left behind


def test_a_shipped_name_resolves_and_an_existing_file_wins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_scenario("relocate") == shipped_scenarios()["relocate"]
    sc = load_scenario("relocate")
    assert (
        sc.name == "relocate" and sc.sha256 == hashlib.sha256(shipped_scenarios()["relocate"].read_bytes()).hexdigest()
    )
    (tmp_path / "relocate").write_text(
        json.dumps([{"tick": 2, "kind": "breakdown", "robot": "eve", "ticks": 2}]), encoding="utf-8"
    )
    assert resolve_scenario("relocate") == Path("relocate")
    ok = CliRunner().invoke(
        main, ["eval", "--dry-run", "--events", "busy_house", "--tasks", "pack_objects", "--scenes", "kitchen"]
    )
    assert ok.exit_code == 0, ok.output
    bad = CliRunner().invoke(main, ["eval", "--dry-run", "--events", "relocate"])  # the local file, not the shipped one
    assert bad.exit_code == 2 and "events[0].robot: 'eve' is not a robot of this episode" in bad.stderr


@pytest.mark.slow
def test_eval_with_a_shipped_name_records_it_and_sends_the_name_to_its_workers(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = CliRunner().invoke(
        main,
        [
            "eval",
            "--events",
            "relocate",
            "--tasks",
            "pack_objects",
            "--scenes",
            "kitchen",
            "--objects",
            "4",
            "--workers",
            "1",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert json.loads((out / "eval.json").read_text())["spec"]["events"] == "relocate"  # the name, not this host's path
    (row,) = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    sha = hashlib.sha256(shipped_scenarios()["relocate"].read_bytes()).hexdigest()
    assert row["scenario"] == "relocate" and row["scenario_sha256"] == sha
    (event,) = row["recovery"]
    assert event["kind"] == "relocate" and event["tick"] == 8 and "ticks_to_recover" in event
    assert (
        f"scenario relocate@{sha[:12]}" in (out / "summary.md").read_text()
        and "recovery (steps)" in (out / "summary.md").read_text()
    )
