"""Issue 42, items 3 to 7: what a hostile trace, team, name or path gets: one line and exit 2 (or the
env's clear error), never a traceback, and nothing written before the refusal.

Commands are real `mhrc` subprocesses (or click's runner where the command is pure), in a scratch
directory; the traces are real recorded episodes, tampered the way the issue's probe did."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process


def _mhrc(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run(
        [sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env
    )


def _one_line(out: Any, code: int = 2) -> str:
    """The command's single line of refusal, after checking it is one line, `code`, no traceback."""
    text = out.output if hasattr(out, "output") else out.stderr + out.stdout
    rc = out.exit_code if hasattr(out, "exit_code") else out.returncode
    assert rc == code, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text[-3000:]
    return lines[0]


# --------------------------------------------------------------------------- mhrc show on a malformed trace


@pytest.fixture(scope="module")
def trace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("hostile") / "trace.jsonl"
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, horizon=4, trace=path).resolved()))
    return path


def _first(rows: list[dict[str, Any]], kind: str) -> dict[str, Any]:
    return next(r["msg"] for r in rows if isinstance(r["msg"], dict) and r["msg"].get("kind") == kind)


def _robot_x_a_string(rows: list[dict[str, Any]]) -> None:
    robots = _first(rows, "snapshot")["robots"]
    robots[next(iter(robots))]["x"] = "far"


def _object_a_list(rows: list[dict[str, Any]]) -> None:
    _first(rows, "snapshot")["objects"] = [1, 2]


def _observation_a_list(rows: list[dict[str, Any]]) -> None:
    _first(rows, "action_result")["observation"] = [1]


def _metrics_a_list(rows: list[dict[str, Any]]) -> None:
    _first(rows, "episode_done")["metrics"] = [1, 2]


def _reply_a_list(rows: list[dict[str, Any]]) -> None:
    _first(rows, "thought")["reply"] = ["a", "list"]


def _started_a_number(rows: list[dict[str, Any]]) -> None:
    _first(rows, "action_result")["started"] = "soon"


def _position_nan(rows: list[dict[str, Any]]) -> None:
    robots = _first(rows, "snapshot")["robots"]
    robots[next(iter(robots))]["y"] = float("nan")


TAMPERED: dict[str, Callable[[list[dict[str, Any]]], None]] = {
    "a string where a number belongs": _robot_x_a_string,
    "a list where the objects belong": _object_a_list,
    "a list where the observation belongs": _observation_a_list,
    "a metrics list": _metrics_a_list,
    "a list where a reply belongs": _reply_a_list,
    "a string where a time belongs": _started_a_number,
    "NaN where a position belongs": _position_nan,
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_show_names_the_malformed_line_in_one_line(trace: Path, tmp_path: Path, case: str) -> None:
    """Each crashed `mhrc show` (ValueError, TypeError or AttributeError in viewer/model.py, page.py,
    page_lanes.py): now one line naming the tampered line, exit 2, and no report written."""
    rows = [json.loads(line) for line in trace.read_text(encoding="utf-8").splitlines()]
    before = [json.dumps(r) for r in rows]
    TAMPERED[case](rows)
    after = [json.dumps(r) for r in rows]
    number = next(i for i, (a, b) in enumerate(zip(before, after, strict=True), 1) if a != b)
    bad = tmp_path / "bad.jsonl"
    bad.write_text("".join(line + "\n" for line in after), encoding="utf-8")
    said = _one_line(CliRunner().invoke(main, ["show", str(bad)]))
    assert said.startswith("mhrc show: ") and f"line {number}: " in said, said
    assert not bad.with_suffix(".html").exists()


def test_show_still_renders_the_untampered_trace(trace: Path, tmp_path: Path) -> None:
    out = tmp_path / "ok.html"
    result = CliRunner().invoke(main, ["show", str(trace), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.is_file()
