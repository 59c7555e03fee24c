"""Issue 42, items 3 to 7: what a hostile trace, team, name or path gets: one line and exit 2 (or the
env's clear error), never a traceback, and nothing written before the refusal.

Commands are real `mhrc` subprocesses (or click's runner where the command is pure), in a scratch
directory; the traces are real recorded episodes, tampered the way the issue's probe did."""

from __future__ import annotations

import asyncio
import json
import os
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from sweep import sweep

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


# --------------------------------------------------------------------------- teams: long, deep, huge, reserved


def _refusal(out: subprocess.CompletedProcess[str]) -> str:
    """A click usage error's one line ("Error: ...", after click's usage lines), exit 2, no traceback."""
    assert out.returncode == 2, out.stderr[-3000:]
    assert "Traceback" not in out.stderr + out.stdout, out.stderr[-3000:]
    said = [ln for ln in out.stderr.splitlines() if ln.strip() and not ln.startswith(("Usage:", "Try '"))]
    assert len(said) == 1, out.stderr
    return said[0]


LONG_TEAM = ",".join(f"{c * 32}={'tabletop_arm' if c == 'a' else 'mobile_manipulator'}" for c in "abcdefgh")


def test_a_valid_inline_team_over_255_characters_is_read_as_robots(tmp_path: Path) -> None:
    """`Path(text).is_file()` raised OSError (file name too long) in mhrc/run/teams.py."""
    from mhrc.run.teams import resolve_team

    assert len(LONG_TEAM) > 255
    assert len(resolve_team(LONG_TEAM).robots) == 8
    out = _mhrc("teams", LONG_TEAM, cwd=tmp_path)
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr[-3000:]
    assert "hhhhhhhhhhhhhhhhhhhhhhhhhhhhhhhh: mobile_manipulator" in out.stdout


@pytest.mark.slow
def test_a_long_inline_team_in_eval_dry_run(tmp_path: Path) -> None:
    out = _mhrc("eval", "--dry-run", "--team", LONG_TEAM, "--out", "ev", cwd=tmp_path)
    assert "Traceback" not in out.stderr and "File name too long" not in out.stderr, out.stderr[-3000:]
    assert out.returncode == 0, out.stderr[-3000:]


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_a_deeply_nested_team_file_is_one_line(tmp_path: Path, suffix: str) -> None:
    """RecursionError in core/team.py before."""
    deep = "[" * 100_000 + "]" * 100_000
    f = tmp_path / f"deep{suffix}"
    if suffix == ".json":
        f.write_text('{"robots": [], "purpose": ' + deep + "}")
    else:
        f.write_text(f"purpose = {deep}\n")
    said = _refusal(_mhrc("teams", f.name, cwd=tmp_path))
    assert "nested too deeply" in said, said


def test_a_deeply_nested_inline_json_team_is_one_line() -> None:
    from mhrc.core.team import TeamError, TeamProblem
    from mhrc.run.teams import resolve_team

    with pytest.raises(TeamError) as err:
        resolve_team('{"robots": ' + "[" * 100_000 + "]" * 100_000 + "}")
    assert err.value.code is TeamProblem.BAD_FILE and "\n" not in str(err.value)


@pytest.mark.parametrize(
    "start", ["[1e308, 0.0, 0.0]", "[0.0, -1e308, 0.0]", "[0.0, 0.0, 1e308]", "[5000.0, 0.0, 0.0]"]
)
def test_a_start_past_any_map_is_refused_at_validation(tmp_path: Path, start: str) -> None:
    """`"start": [1e308, ...]` overflowed in world/astar.py when the world placed the team."""
    (tmp_path / "far.toml").write_text(
        f'[[robots]]\nname = "alice"\nkind = "mobile_manipulator"\nstart = {start}\n'
        '[[robots]]\nname = "bob"\nkind = "tabletop_arm"\n'
    )
    said = _refusal(_mhrc("up", "--team", "far.toml", "--horizon", "2", "--insecure", cwd=tmp_path))
    assert "robots.0.start" in said and "finite coordinate" in said, said
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("name", sweep(["world", "observer", "robots", "visible"]))  # two mhrc processes a case
def test_a_robot_named_like_a_participant_is_refused_before_anything_is_written(tmp_path: Path, name: str) -> None:
    """`--team world=...` passed validation and wrote runs/RUN/credentials (the world's key
    included) before Zenoh refused; `mhrc credentials --team world=...` exited 0 handing robot
    `world` the world's login. `robots` and `visible` repeated an id of the router's rules."""
    team = f"{name}=mobile_manipulator,bob=tabletop_arm"
    said = _refusal(_mhrc("up", "--team", team, "--horizon", "2", cwd=tmp_path))
    assert "robots.0.name" in said and repr(name) in said, said
    said = _refusal(_mhrc("credentials", "--team", team, "--out", "creds", cwd=tmp_path))
    assert repr(name) in said, said
    assert list(tmp_path.iterdir()) == []


def test_the_credentials_refuse_a_reserved_robot_name_before_writing(tmp_path: Path) -> None:
    from mhrc.core.participants import RESERVED
    from mhrc.core.security import SecurityError, make_run_credentials

    for name in sorted(RESERVED):
        with pytest.raises(SecurityError):
            make_run_credentials("r1", ["alice", name], tmp_path / name)
        assert not (tmp_path / name).exists()


def test_every_name_the_router_rules_give_a_participant_is_reserved() -> None:
    """The reserved names come from the bus: a robot named like one repeats an id of the access rules
    (or a login); any other robot name keeps every id unique."""
    from mhrc.core.participants import RESERVED
    from mhrc.core.security import OBSERVER, WORLD, acl

    def unique(robots: list[str]) -> bool:  # the router wants each rule's, subject's and policy's id once
        conf = acl("r1", robots)
        return all(len({i["id"] for i in conf[part]}) == len(conf[part]) for part in ("rules", "subjects", "policies"))

    assert {WORLD, OBSERVER} <= RESERVED
    for name in RESERVED - {WORLD, OBSERVER}:
        assert not unique(["alice", name]), name
    conf = acl("r1", ["alice"])
    words = {w for part in ("rules", "subjects", "policies") for i in conf[part] for w in i["id"].split("-")}
    clean = sorted(w for w in words if w.isidentifier() and w not in RESERVED and w != "alice")
    assert unique(["alice", *clean]), clean


# --------------------------------------------------------------------------- the AEC env's misuse errors


def test_the_aec_env_says_step_before_reset_and_after_the_last_agent_left() -> None:
    """AttributeError before reset and KeyError 'alice' after every agent left; now ValueErrors
    that say what to do, as the parallel env's are, and the env still runs after them."""
    import mhrc.env as mhrc_env

    aec = mhrc_env.env(objects=3, horizon=1)
    try:
        with pytest.raises(ValueError, match="before reset"):
            aec.step("wait()")
        aec.reset(seed=0)
        for _ in aec.possible_agents:
            aec.step("wait()")
        while aec.agents:
            aec.step(None)
        for action in ("wait()", None):
            with pytest.raises(ValueError, match="no live agent.*reset"):
                aec.step(action)
        aec.reset(seed=1)  # another episode runs as ever
        assert aec.agents == aec.possible_agents
        aec.step("wait()")
    finally:
        aec.close()

    par = mhrc_env.parallel_env(objects=3, horizon=1)
    try:
        with pytest.raises(ValueError, match="not live"):
            par.step({"alice": "wait()"})
    finally:
        par.close()


# --------------------------------------------------------------------------- --rerun OUT.rrd: a regular file only


def _odd_rrd(kind: str, where: Path) -> Path:
    out = where / "out.rrd"
    if kind == "fifo":
        os.mkfifo(out)
    elif kind == "symlink":
        (where / "elsewhere.rrd").write_bytes(b"")
        out.symlink_to(where / "elsewhere.rrd")
    elif kind == "dangling symlink":
        out.symlink_to(where / "nowhere.rrd")
    elif kind == "device":
        return _device_rrd(where)
    return out


def _device_rrd(where: Path) -> Path:
    """A character device named *.rrd: a link would be refused as a link, so a device node where
    we may make one (as root), else skip."""
    out = where / "dev.rrd"
    try:
        os.mknod(out, 0o600 | stat.S_IFCHR, os.makedev(1, 3))  # /dev/null's numbers
    except PermissionError:
        pytest.skip("making a device node needs root")
    return out


@pytest.mark.parametrize("kind", ["fifo", "symlink", "dangling symlink", "device"])
def test_rerun_refuses_what_is_not_a_regular_file(trace: Path, tmp_path: Path, kind: str) -> None:
    """A FIFO as `--rerun OUT.rrd` hung for over 60 s; a symlinked .rrd was written through to its
    target. Now one line and exit 2 before anything is written."""
    pytest.importorskip("rerun")
    out = _odd_rrd(kind, tmp_path)
    target = tmp_path / "elsewhere.rrd"
    said = _refusal(_mhrc("show", str(trace), "--rerun", str(out), cwd=tmp_path, timeout=30))
    assert "--rerun" in said and str(out) in said, said
    assert not target.exists() or target.stat().st_size == 0
    assert not (tmp_path / "nowhere.rrd").exists()


def test_rerun_still_writes_a_regular_file(trace: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    out = _mhrc("show", str(trace), "--rerun", "rec.rrd", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "rec.rrd").is_file() and (tmp_path / "rec.rrd").stat().st_size > 0
