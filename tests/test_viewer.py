"""`mhrc show`: the HTML report of real recorded episodes, and what it does with bad input."""

from __future__ import annotations

import asyncio
import json
import re
import threading
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.episode import EpisodeConfig, up_in_process
from mhrc.trace import read_trace
from test_llm import FakeServer, Reply, ok


def record_heuristic(path: Path, horizon: int = 30) -> Path:
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, horizon=horizon, trace=path).resolved()))
    return path


def record_llm(path: Path) -> Path:
    """Three LLM robots against a scripted server: a navigation, a message, a failed pick."""
    replies = {
        "alice": ["Analysis: I will look at table_1 first.\nCommand: navigate(table_1, 0)",
                  'Analysis: Bob should know.\nCommand: communicate("I am at table_1", bob)'],
        "bob": ["Analysis: the ghost is near.\nCommand: pick(ghost)"],
        "david": ["Command: navigate(table_2, 0)"],
    }
    lock = threading.Lock()

    def respond(body: dict[str, Any]) -> Reply:
        robot = body["messages"][0]["content"].split()[2].rstrip(",").lower()  # "You are Alice, ..."
        with lock:
            text = replies[robot].pop(0) if replies[robot] else "Analysis: nothing to do.\nCommand: wait()"
        return ok(text)

    server = FakeServer(respond)
    try:
        cfg = EpisodeConfig.build(seed=0, horizon=4, llm="openai:test-model", base_url=server.url, trace=path).resolved()
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
    return {"heuristic": record_heuristic(d / "heuristic" / "trace.jsonl"), "llm": record_llm(d / "llm.jsonl")}


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
    rows = read_trace(trace)
    msgs = [r["msg"] for r in rows if isinstance(r["msg"], dict)]
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
            1 for s in with_result if any(r["goal_id"] == s["data-goal"] and r["robot"] == robot for r in results))

    # every snapshot's data, in order
    data = json.loads(page.data_json)
    snaps = [m for m in msgs if m["kind"] == "snapshot"]
    assert len(data["frames"]) == len(snaps) > 1
    for frame, snap in zip(data["frames"], snaps):
        assert frame["tick"] == snap["tick"] and frame["goals"] == snap["goals"]
        assert frame["robots"] == snap["robots"] and frame["objects"] == snap["objects"] and frame["open"] == snap["open"]
    assert data["framesFrom"] == "snapshots"
    # every executed step points at the frame right after it
    for s in with_result:
        frame = data["frames"][int(str(s["data-frame"]))]
        assert s["data-goal"] in frame["goals"]

    # the header: task, scene, seed, models, fidelity, scheduler, metrics, the TS lower bound
    done = next(m for m in msgs if m["kind"] == "episode_done")
    for text in (started["task"], started["scene"], started["fidelity"], started["scheduler"], "TS lower bound", "makespan"):
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
    thoughts = [r["msg"] for r in read_trace(traces["llm"]) if isinstance(r["msg"], dict) and r["msg"]["kind"] == "thought"]
    assert thoughts and all(t["prompt"] for t in thoughts)
    assert page.details >= 2 * len(thoughts)  # prompt and raw reply of each step
    assert "llm:test-model" in html
    assert "I will look at table_1 first." in html and "pick(ghost)" in html
    assert "prompt + 7 completion tokens" in html
    first_prompt = thoughts[0]["prompt"]
    from html import escape

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


def test_an_older_trace_without_snapshots_shows_the_robots_from_their_observations(traces: dict[str, Path], tmp_path: Path) -> None:
    old = tmp_path / "v1.jsonl"
    with old.open("w", encoding="utf-8") as f:
        for row in read_trace(traces["heuristic"]):
            msg = row["msg"]
            if isinstance(msg, dict):
                if msg["kind"] == "snapshot":
                    continue
                msg["v"] = 1
            f.write(json.dumps(row) + "\n")
    result = show(str(old))
    assert result.exit_code == 0, result.output
    assert "no snapshot" in result.output and len(result.output.strip().splitlines()) == 2  # the warning, the path
    html = old.with_suffix(".html").read_text(encoding="utf-8")
    page = parse(html)
    assert page.warnings >= 1 and "no snapshot" in html
    data = json.loads(page.data_json)
    assert data["framesFrom"] == "observations" and data["frames"]
    assert all(set(f["robots"]) <= {"alice", "bob", "david"} and not f["objects"] for f in data["frames"])
    assert any(f["robots"]["alice"]["x"] != data["frames"][0]["robots"]["alice"]["x"] for f in data["frames"] if "alice" in f["robots"])
    results = [r for r in read_trace(old) if isinstance(r["msg"], dict) and r["msg"]["kind"] == "action_result"]
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
    section = html[html.index('<section id="failures">'):]
    section = section[: section.index("</section>")]
    diag, note = diagnostics_for(read_trace(traces["llm"]))
    if diag is None:
        assert note and "note" in section
    else:
        assert "<table" in section
        for key in diag:
            assert f"<th>{key}</th>" in section
