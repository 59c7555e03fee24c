"""`mhrc show`: the HTML report of real recorded episodes, and what it does with bad input."""

from __future__ import annotations

import asyncio
import json
import re
from html import escape
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from old_traces import as_version_1

from mhrc.cli import main
from mhrc.core.protocol import LLM_ERROR_PREFIX
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer


def _msgs(path: Path) -> list[dict[str, Any]]:
    """The trace's messages as mhrc.core.records decodes them (older ones upgraded), as JSON for the checks."""
    return [line.msg.model_dump(mode="json") for line in read_records(path) if line.msg is not None]


def _json_lines(path: Path) -> list[dict[str, Any]]:
    """The trace's lines as written, to write a changed copy of it (an older or a tampered trace)."""
    return [json.loads(text) for text in path.read_text(encoding="utf-8").splitlines() if text.strip()]


def record_heuristic(path: Path, horizon: int = 30) -> Path:
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, horizon=horizon, trace=path).resolved()))
    return path


FAILED_HORIZON = 5  # seed 0's heuristic team places 1 of 4 targets by then (its TS lower bound is 11)


def record_failed(path: Path) -> Path:
    """A heuristic episode cut off by a tiny horizon: some targets placed, some not."""
    record_heuristic(path, horizon=FAILED_HORIZON)
    done = next(m for m in _msgs(path) if m["kind"] == "episode_done")
    m = done["metrics"]
    assert not m["success"] and 0 < m["placed"] < m["total"], m  # the test needs a partial failure
    return path


def record_llm(path: Path) -> Path:
    """Three LLM robots against a scripted server: a navigation, a message, a failed pick."""
    replies = {
        "alice": [
            "Analysis: I will look at table_1 first.\nCommand: navigate(table_1, 0)",
            'Analysis: Bob should know.\nCommand: communicate("I am at table_1", bob)',
        ],
        "bob": ["Analysis: the ghost is near.\nCommand: pick(ghost)"],
        "david": ["Command: navigate(table_2, 0)"],
    }
    usage = {"prompt_tokens": 11, "completion_tokens": 7}
    script = {robot: [ModelReply(text, usage=usage) for text in texts] for robot, texts in replies.items()}
    server = ScriptedModelServer(script, when_done=ModelReply("Analysis: nothing to do.\nCommand: wait()", usage=usage))
    try:
        cfg = EpisodeConfig.build(
            seed=0, horizon=4, llm="openai:test-model", base_url=server.url, trace=path
        ).resolved()
        asyncio.run(up_in_process(cfg))
    finally:
        server.close()
    return path


class Page(HTMLParser):
    """The parts of the report the tests look at."""

    def __init__(self) -> None:
        super().__init__()
        self.steps: list[dict[str, str | None]] = []
        self.ids: set[str] = set()
        self.refs: list[str] = []  # src / href values
        self.data_json = ""
        self._in_data = False
        self.warnings = 0
        self.lanes: list[str] = []
        self.details = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(str(a["id"]))
        for k in ("src", "href"):
            if a.get(k):
                self.refs.append(str(a[k]))
        cls = (a.get("class") or "").split()
        if tag == "li" and "step" in cls:
            self.steps.append(a)
        if "warning" in cls:
            self.warnings += 1
        if "lane" in cls:
            self.lanes.append(str(a.get("data-robot")))
        if tag == "details":
            self.details += 1
        if tag == "script" and a.get("id") == "mhrc-data":
            self._in_data = True

    def handle_endtag(self, tag: str) -> None:
        if tag == "script":
            self._in_data = False

    def handle_data(self, data: str) -> None:
        if self._in_data:
            self.data_json += data


def parse(html: str) -> Page:
    page = Page()
    page.feed(html)
    page.close()
    return page


def show(*args: str) -> Any:
    return CliRunner().invoke(main, ["show", *args])


@pytest.fixture(scope="module")
def traces(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("viewer")
    return {
        "heuristic": record_heuristic(d / "heuristic" / "trace.jsonl"),
        "llm": record_llm(d / "llm.jsonl"),
        "failed": record_failed(d / "failed.jsonl"),
    }


def _self_contained(html: str) -> None:
    page = parse(html)
    assert not [r for r in page.refs if not r.startswith("#")], page.refs
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", html, re.I)
    assert not re.search(r"""url\(\s*["']?\s*(https?:)?//|@import|<link\b|<iframe\b""", html, re.I)
    assert "https://" not in html and "http://" not in html  # nothing to fetch, not even a namespace URL


@pytest.mark.parametrize("kind", ["heuristic", "llm"])
def test_the_report_holds_every_step_and_every_snapshot(traces: dict[str, Path], kind: str, tmp_path: Path) -> None:
    trace = traces[kind]
    out = tmp_path / "report.html"
    result = show(str(trace), "--out", str(out))
    assert result.exit_code == 0, result.output
    assert result.output.strip().splitlines()[-1] == str(out)
    html = out.read_text(encoding="utf-8")
    _self_contained(html)
    page = parse(html)
    msgs = _msgs(trace)
    started = next(m for m in msgs if m["kind"] == "episode_started")
    assert {"map", "tick-slider", "tick-label", "lanes", "failures", "messages", "header"} <= page.ids
    assert page.lanes == started["robots"]
    assert page.warnings == 0

    # every robot's every step: one lane entry per request, each result on its own entry
    results = [m for m in msgs if m["kind"] == "action_result"]
    requests = [m for m in msgs if m["kind"] == "action_request"]
    assert len(page.steps) == len(requests)
    with_result = [s for s in page.steps if "has-result" in str(s["class"]).split()]
    assert sorted(str(s["data-goal"]) for s in with_result) == sorted(r["goal_id"] for r in results)
    for robot in started["robots"]:
        assert sum(1 for r in results if r["robot"] == robot) == sum(
            1 for s in with_result if any(r["goal_id"] == s["data-goal"] and r["robot"] == robot for r in results)
        )

    # every snapshot's data, in order
    data = json.loads(page.data_json)
    snaps = [m for m in msgs if m["kind"] == "snapshot"]
    assert len(data["frames"]) == len(snaps) > 1
    for frame, snap in zip(data["frames"], snaps):
        assert frame["tick"] == snap["tick"] and frame["goals"] == snap["goals"]
        assert (
            frame["robots"] == snap["robots"] and frame["objects"] == snap["objects"] and frame["open"] == snap["open"]
        )
    assert data["framesFrom"] == "snapshots"
    # every executed step points at the frame right after it
    for s in with_result:
        frame = data["frames"][int(str(s["data-frame"]))]
        assert s["data-goal"] in frame["goals"]

    # the header: task, scene, seed, models, fidelity, scheduler, metrics, the TS lower bound
    done = next(m for m in msgs if m["kind"] == "episode_done")
    for text in (
        started["task"],
        started["scene"],
        started["fidelity"],
        started["scheduler"],
        "TS lower bound",
        "makespan",
    ):
        assert text in html
    assert f">{started['lower_bound']}<" in html and f">{done['metrics']['temporal_steps']}<" in html

    # every message, from sender to receiver, with the tick it was sent at
    sent = [m for m in msgs if m["kind"] == "message"]
    assert len(data["messages"]) == len(sent) > 0
    for m, d in zip(sent, data["messages"]):
        assert (d["sender"], d["to"], d["content"], d["sent"]) == (m["sender"], m["to"], m["content"], m["tick"])
    if started["scheduler"] != "async":
        assert all(d["delivered"] is None or d["delivered"] == d["sent"] + 1 for d in data["messages"])
        assert any(d["delivered"] == d["sent"] + 1 for d in data["messages"])


def test_llm_steps_show_the_analysis_command_prompt_and_reply(traces: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "llm.html"
    assert show(str(traces["llm"]), "--out", str(out)).exit_code == 0
    html = out.read_text(encoding="utf-8")
    page = parse(html)
    thoughts = [m for m in _msgs(traces["llm"]) if m["kind"] == "thought"]
    assert thoughts and all(t["prompt"] for t in thoughts)
    assert page.details >= 2 * len(thoughts)  # prompt and raw reply of each step
    assert "llm:test-model" in html
    assert "I will look at table_1 first." in html and "pick(ghost)" in html
    assert "prompt + 7 completion tokens" in html
    first_prompt = thoughts[0]["prompt"]
    assert escape(first_prompt, quote=True) in html  # the full prompt, not a summary


def test_a_run_directory_writes_beside_its_trace(traces: dict[str, Path]) -> None:
    run = traces["heuristic"].parent
    result = show(str(run))
    assert result.exit_code == 0, result.output
    assert Path(result.output.strip()) == run / "trace.html" and (run / "trace.html").exists()


def test_a_truncated_trace_renders_what_it_can_with_a_warning(traces: dict[str, Path], tmp_path: Path) -> None:
    text = traces["heuristic"].read_text(encoding="utf-8")
    cut = tmp_path / "cut.jsonl"
    cut.write_text(text[: len(text) // 2], encoding="utf-8")  # mid-line, almost surely
    if cut.read_text().endswith("\n"):
        cut.write_text(text[: len(text) // 2 - 5], encoding="utf-8")
    result = show(str(cut))
    assert result.exit_code == 0
    warning_lines = [ln for ln in result.output.splitlines() if "warning" in ln]
    assert len(warning_lines) == 1 and "truncated" in warning_lines[0], result.output
    html = cut.with_suffix(".html").read_text(encoding="utf-8")
    page = parse(html)
    assert page.warnings >= 1 and "truncated" in html and "Traceback" not in result.output
    kept = [json.loads(ln) for ln in text[: len(text) // 2].splitlines()[:-1]]
    requests = [r for r in kept if isinstance(r["msg"], dict) and r["msg"]["kind"] == "action_request"]
    assert len(page.steps) == len(requests) > 0


def test_an_older_trace_without_snapshots_shows_the_robots_from_their_observations(
    traces: dict[str, Path], tmp_path: Path
) -> None:
    old = as_version_1(traces["heuristic"], tmp_path / "v1.jsonl")
    result = show(str(old))
    assert result.exit_code == 0, result.output
    assert "no snapshot" in result.output and len(result.output.strip().splitlines()) == 2  # the warning, the path
    html = old.with_suffix(".html").read_text(encoding="utf-8")
    page = parse(html)
    assert page.warnings >= 1 and "no snapshot" in html
    data = json.loads(page.data_json)
    assert data["framesFrom"] == "observations" and data["frames"]
    assert all(set(f["robots"]) <= {"alice", "bob", "david"} and not f["objects"] for f in data["frames"])
    assert any(
        f["robots"]["alice"]["x"] != data["frames"][0]["robots"]["alice"]["x"]
        for f in data["frames"]
        if "alice" in f["robots"]
    )
    results = [m for m in _msgs(old) if m["kind"] == "action_result"]
    assert sum(1 for s in page.steps if "has-result" in str(s["class"])) == len(results)


@pytest.mark.parametrize("content", ["hello, this is not a trace\n", '{"a": 1}\n[1, 2]\n', "", "\x00\x01binary"])
def test_not_a_trace_is_one_line_and_exit_2(tmp_path: Path, content: str) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text(content, encoding="utf-8")
    result = show(str(bad))
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    assert str(bad) in result.output and not bad.with_suffix(".html").exists()


def test_a_missing_trace_or_empty_run_directory_is_one_line_and_exit_2(tmp_path: Path) -> None:
    for target in (tmp_path / "nothing.jsonl", tmp_path):
        result = show(str(target))
        assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1
        assert "does not exist" in result.output


def test_the_failure_panel_renders_the_diagnosis_or_a_note(traces: dict[str, Path], tmp_path: Path) -> None:
    from mhrc.viewer.show import diagnostics_for

    out = tmp_path / "d.html"
    assert show(str(traces["llm"]), "--out", str(out)).exit_code == 0
    html = out.read_text(encoding="utf-8")
    section = html[html.index('<section id="failures">') :]
    section = section[: section.index("</section>")]
    from mhrc.analysis.diagnostics import LABELS

    diag, note = diagnostics_for(read_records(traces["llm"]))
    assert diag is not None, note
    assert "<table" in section
    for key in diag.as_dict():  # every finding, under the label people read, the key in its title
        assert f'<th title="{key}">{escape(LABELS[key])}</th>' in section
    assert "hallucinated names" in section and "hallucinated_names</th>" not in section
    assert not re.search(r"<th[^>]*>[a-z]+_[a-z_]+</th>", section)  # no raw key as a row's heading


def test_the_failure_panel_says_why_when_the_diagnosis_fails(traces: dict[str, Path], tmp_path: Path) -> None:
    from mhrc.viewer.load import load_trace
    from mhrc.viewer.model import build_view
    from mhrc.viewer.page import render_page

    html = render_page(
        build_view(load_trace(traces["llm"])), None, "the failure diagnosis failed on this trace: KeyError: 'x'"
    )
    section = html[html.index('<section id="failures">') :]
    assert "KeyError" in section[: section.index("</section>")] and 'class="note"' in section
    # the paper's protocol decides robot by robot: no coordination section, no protocol fact, no job lines
    assert 'id="coordination"' not in html and "<th>protocol</th>" not in html and 'class="coordination' not in html


def _data(html: str) -> dict[str, Any]:
    return json.loads(parse(html).data_json)


def _report(trace: Path, tmp_path: Path, name: str = "r.html") -> str:
    out = tmp_path / name
    result = show(str(trace), "--out", str(out))
    assert result.exit_code == 0, result.output
    return out.read_text(encoding="utf-8")


class Rows(HTMLParser):
    """The Targets section's rows: data-name, data-role, data-placed and the cells' text."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, Any]] = []
        self._row: dict[str, Any] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "tr" and a.get("data-role"):
            self._row = {"name": a["data-name"], "role": a["data-role"], "placed": a["data-placed"], "cells": []}
            self.rows.append(self._row)
        elif tag == "td" and self._row is not None:
            self._row["cells"].append("")

    def handle_endtag(self, tag: str) -> None:
        if tag == "tr":
            self._row = None

    def handle_data(self, data: str) -> None:
        if self._row is not None and self._row["cells"]:
            self._row["cells"][-1] += data


def _targets_section(html: str) -> str:
    start = html.index('<section id="targets">')
    return html[start : html.index("</section>", start)]


def _truth(trace: Path) -> tuple[list[str], dict[str, Any], dict[str, Any]]:
    """Bob's target list, the last snapshot's objects and the world's metrics, straight from the trace."""
    msgs = _msgs(trace)
    targets = next(m["observation"]["targets"] for m in msgs if m["kind"] == "action_result" and m["robot"] == "bob")
    last = [m for m in msgs if m["kind"] == "snapshot"][-1]["objects"]
    return targets, last, next(m for m in msgs if m["kind"] == "episode_done")["metrics"]


def test_a_failed_episode_names_its_targets_the_unplaced_ones_and_where_they_ended(
    traces: dict[str, Path], tmp_path: Path
) -> None:
    html = _report(traces["failed"], tmp_path)
    targets, last, metrics = _truth(traces["failed"])
    section = _targets_section(html)
    assert html.index('<section id="targets">') < html.index(
        '<section id="map-section">'
    )  # near the top, before the map
    parser = Rows()
    parser.feed(section)
    rows = {r["name"]: r for r in parser.rows}
    assert [r["name"] for r in parser.rows if r["role"] == "target"] == targets  # in the task's order
    assert {n for n, r in rows.items() if r["role"] == "distractor"} == set(last) - set(targets) != set()
    unplaced = [t for t in targets if last[t]["on"] != "tray" or last[t]["held_by"]]
    assert [n for n, r in rows.items() if r["placed"] == "no"] == unplaced
    assert len(targets) - len(unplaced) == metrics["placed"] and len(targets) == metrics["total"]
    assert f"{len(unplaced)} of {len(targets)} targets not placed" in section
    for t in unplaced:  # where each unplaced target was last
        pose = last[t]
        where = f"held by {pose['held_by']}" if pose["held_by"] else f"{'in' if pose['inside'] else 'on'} {pose['on']}"
        assert rows[t]["cells"][3] == where and f"<b>{t}</b> ({where})" in section
        assert rows[t]["cells"][2] == "tray"
    # the map's script styles each object by its role and goal
    data = _data(html)
    assert data["roles"] == {n: r["role"] for n, r in rows.items()}
    assert data["goals"] == {t: "tray" for t in targets}


def test_a_solved_episode_has_every_target_placed(traces: dict[str, Path], tmp_path: Path) -> None:
    html = _report(traces["heuristic"], tmp_path)
    targets, _, metrics = _truth(traces["heuristic"])
    assert metrics["success"]
    parser = Rows()
    parser.feed(_targets_section(html))
    assert [r["name"] for r in parser.rows if r["placed"] == "yes"] == targets
    assert f"All {len(targets)} targets placed." in html


def test_targets_come_from_the_task_when_the_trace_does_not_name_them(traces: dict[str, Path], tmp_path: Path) -> None:
    """A trace whose observations carry no target list (say, Bob never acted): the task's generator names them, and says so."""
    bare = tmp_path / "bare.jsonl"
    with bare.open("w", encoding="utf-8") as f:
        for row in _json_lines(traces["failed"]):
            msg = row["msg"]
            if isinstance(msg, dict) and isinstance(msg.get("observation"), dict):
                msg["observation"]["targets"] = []
            if isinstance(msg, dict) and msg.get("kind") == "episode_done":  # as a world before the answer key was sent
                msg.pop("targets", None), msg.pop("goals", None)
            f.write(json.dumps(row) + "\n")
    targets, _, _ = _truth(traces["failed"])
    section = _targets_section(_report(bare, tmp_path))
    parser = Rows()
    parser.feed(section)
    assert sorted(r["name"] for r in parser.rows if r["role"] == "target") == sorted(targets)
    assert "task&#x27;s generator" in section or "task's generator" in section


def test_the_worlds_answer_key_comes_first(traces: dict[str, Path], tmp_path: Path) -> None:
    """The world names the task's targets, goals and order in episode_done (once nobody can use
    them): the report takes them from there, before Bob's observations."""
    targets, last, _ = _truth(traces["failed"])
    done = next(m for m in _msgs(traces["failed"]) if m["kind"] == "episode_done")
    assert done["targets"] == targets and done["goals"] == {t: "tray" for t in targets} and done["ordered"] is False
    named = tmp_path / "named.jsonl"
    with named.open("w", encoding="utf-8") as f:
        for row in _json_lines(traces["failed"]):
            msg = row["msg"]
            if isinstance(msg, dict) and msg.get("kind") == "episode_done":
                msg["targets"] = targets[::-1]
            f.write(json.dumps(row) + "\n")
    section = _targets_section(_report(named, tmp_path))
    parser = Rows()
    parser.feed(section)
    assert [r["name"] for r in parser.rows if r["role"] == "target"] == targets[::-1]
    assert "targets from the world (its episode_done event); goals from the world (its episode_done event)" in section


def test_partial_success_reads_the_same_everywhere(traces: dict[str, Path], tmp_path: Path) -> None:
    from mhrc.eval.html import html_summary
    from mhrc.eval.records import upgrade_row

    for kind in ("failed", "heuristic"):
        _, _, m = _truth(traces[kind])
        expected = f"{m['partial_success']:.2f} ({m['placed']}/{m['total']} placed)"
        html = _report(traces[kind], tmp_path, f"{kind}.html")
        box = re.search(r'data-metric="partial_success"><div class="mv">(.*?)</div>', html)
        assert box and re.sub(r"<[^>]+>", "", box.group(1)) == expected
        assert f"<td>{expected}</td>" in html  # the "all metrics" table
    row = {
        "key": "pack_objects/kitchen/3/0",
        "method": "heuristic",
        "ablation": "none",
        "fidelity": "paper",
        "history_cap": None,
        "horizon": 30,
        "aids": [],
        "repeat": 0,
        "trial": 0,
        "task": "pack_objects",
        "scene": "kitchen",
        "seed": 0,
        "n_objects": 3,
        "robots": ["alice", "bob", "david"],
        "success": False,
        "partial_success": 1 / 3,
        "placed": 1,
        "total": 3,
        "temporal_steps": 30,
        "action_steps": 20,
        "lower_bound": 9,
        "valid": True,
        "invalid_reason": None,
        "schedule": "lockstep",
        "messages": 2,
        "llm_calls": 0,
        "prompt_tokens": 0,
        "completion_tokens": 0,
        "failed_actions": {},
        "wall_time": 1.0,
        "parse_failures": 0,
        "llm_unreachable": 0,
        "rejected_actions": 0,
    }
    row |= {"reason": "horizon", "action_steps_per_robot": {}}
    assert "<td>0.33 (1/3 placed)</td>" in html_summary([upgrade_row(row)], [None], resamples=50)


def test_the_page_opens_on_the_last_frame(traces: dict[str, Path], tmp_path: Path) -> None:
    html = _report(traces["failed"], tmp_path)
    n = len(_data(html)["frames"])
    slider = re.search(r'<input type="range" id="tick-slider"[^>]*>', html)
    assert slider and f'max="{n - 1}"' in slider.group(0) and f'value="{n - 1}"' in slider.group(0)
    assert "draw(last)" in html


WALL_MARGIN = 0.02  # m: a route may graze a wall's box by a rounding centimetre


def _crosses_wall(a: tuple[float, float], b: tuple[float, float], walls: list[list[float]]) -> bool:
    for k in range(101):
        x, y = a[0] + (b[0] - a[0]) * k / 100, a[1] + (b[1] - a[1]) * k / 100
        for cx, cy, sx, sy in walls:
            if abs(x - cx) < sx / 2 - WALL_MARGIN and abs(y - cy) < sy / 2 - WALL_MARGIN:
                return True
    return False


def test_paths_follow_the_planned_routes_around_walls(traces: dict[str, Path], tmp_path: Path) -> None:
    from mhrc.world.layouts import get_layout

    trace = traces["heuristic"]
    data = _data(_report(trace, tmp_path))
    walls = [list(w) for w in get_layout("kitchen").walls]
    msgs = _msgs(trace)
    navigates = [
        m
        for m in msgs
        if m["kind"] == "action_result"
        and m["action"]["skill"] == "navigate"
        and m["outcome"]["code"] in ("ok", "off_target")
    ]
    assert navigates and set(data["routes"]) == {m["goal_id"] for m in navigates}
    frame_of = {g: i for i, f in enumerate(data["frames"]) for g in f["goals"]}
    straight_crossings = 0
    for m in navigates:
        route = data["routes"][m["goal_id"]]
        assert 2 <= len(route) <= 40 and all(round(v, 2) == v for p in route for v in p)
        i = frame_of[m["goal_id"]]
        before, after = data["frames"][i - 1]["robots"][m["robot"]], data["frames"][i]["robots"][m["robot"]]
        assert route[0] == pytest.approx([before["x"], before["y"]], abs=0.006)  # from where it stood
        assert route[-1] == pytest.approx([after["x"], after["y"]], abs=0.006)  # to where it stopped
        assert not any(_crosses_wall(tuple(a), tuple(b), walls) for a, b in zip(route, route[1:])), route
        straight_crossings += _crosses_wall((before["x"], before["y"]), (after["x"], after["y"]), walls)
    assert straight_crossings > 0  # the straight lines the map drew before went through walls


def test_an_older_trace_without_routes_still_loads_and_draws_straight_lines(
    traces: dict[str, Path], tmp_path: Path
) -> None:
    from mhrc.core.protocol import ActionResult

    old = tmp_path / "noroutes.jsonl"
    with old.open("w", encoding="utf-8") as f:
        for row in _json_lines(traces["heuristic"]):
            msg = row["msg"]
            if isinstance(msg, dict) and msg.get("kind") == "action_result":
                msg["outcome"].pop("path", None)
                assert ActionResult.model_validate(msg).outcome.path is None  # still a valid message
            f.write(json.dumps(row) + "\n")
    html = _report(old, tmp_path)
    assert _data(html)["routes"] == {} and parse(html).warnings == 0


def _label_boxes(html: str) -> list[tuple[str, float, float, float, float]]:
    """The fixed labels of the map's SVG as boxes, estimated independently of the page's own
    estimate: 0.55 em a character, 1.2 em high, anchored in the middle on the baseline."""
    svg = html[html.index('<g id="static">') : html.index('<g id="dyn">')]
    boxes = []
    for m in re.finditer(r"<text\b([^>]*)>([^<]*)</text>", svg):
        attrs = dict(re.findall(r'([\w-]+)="([^"]*)"', m.group(1)))
        font = float(attrs.get("font-size", 11))
        x, y, w = float(attrs["x"]), float(attrs["y"]), len(m.group(2)) * font * 0.55
        boxes.append((m.group(2), x - w / 2, y - 0.95 * font, x + w / 2, y + 0.25 * font))
    return boxes


def test_no_two_map_labels_overlap_in_the_kitchen(traces: dict[str, Path], tmp_path: Path) -> None:
    from mhrc.world.layouts import get_layout

    for kind in ("heuristic", "failed"):
        html = _report(traces[kind], tmp_path, f"{kind}.html")
        boxes = _label_boxes(html)
        names = {f.name for f in get_layout("kitchen").furniture}
        assert {b[0].removesuffix(" ▣") for b in boxes} == names | {"goal area"}
        vb = re.search(r'<svg id="map" viewBox="0 0 ([\d.]+) ([\d.]+)"', html)
        assert vb
        for i, a in enumerate(boxes):
            assert a[1] >= 0 and a[2] >= 0 and a[3] <= float(vb.group(1)) and a[4] <= float(vb.group(2)), a
            for b in boxes[i + 1 :]:
                assert min(a[3], b[3]) <= max(a[1], b[1]) or min(a[4], b[4]) <= max(a[2], b[2]), (a, b)


def test_an_older_trace_renders_with_its_upgraded_values(traces: dict[str, Path], tmp_path: Path) -> None:
    """A trace as mhrc wrote it before thoughts carried `failure` and acks a reject code: the report shows the
    codes mhrc.core.upgrade reads from their texts (the page reads decoded messages, never the JSON as written)."""
    old = tmp_path / "old.jsonl"
    rows = _json_lines(traces["llm"])
    thought = next(r["msg"] for r in rows if isinstance(r["msg"], dict) and r["msg"].get("kind") == "thought")
    thought.pop("failure", None)
    thought["parse_error"] = LLM_ERROR_PREFIX + "m at http://x failed after 5 attempts: HTTP 503"
    ack = next(r["msg"] for r in rows if isinstance(r["msg"], dict) and r["msg"].get("kind") == "action_ack")
    ack.update(accepted=False, reason="the request is for tick 3 but alice is at tick 4")
    ack.pop("code", None)
    old.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    html = _report(old, tmp_path)
    assert 'data-failure="model_unreachable"' in html and "(model unreachable)" in html
    assert 'data-code="stale_tick"' in html
    assert html.count("data-failure=") == 1 and html.count("data-code=") == 1  # today's lines carry no such failure
