"""Rerun recordings (issue 35): from a trace (`mhrc show --rerun`), live while an episode runs (`mhrc up
--rerun`, and the live recording of a scripted-model episode), read back with rerun-sdk's own reader
(rerun.chunk.RrdReader) and checked with `rerun rrd verify`; bad inputs."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import signal
import subprocess
import sys
import urllib.request
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from old_traces import as_version_1

from mhrc.cli import main
from mhrc.core.protocol import EpisodeDone
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer
from mhrc.viewer.rerun import Mode, Target  # imports no rerun-sdk
from mhrc.world.kinds import KINDS, flight_altitude
from mhrc.world.layouts import get_layout

# rerun-sdk (some 500 modules) is imported by the tests that use it, not by every worker that collects them
pytestmark = pytest.mark.skipif(importlib.util.find_spec("rerun") is None, reason="rerun-sdk is not installed")

TEAM = "scout_and_drone"  # alice, bob, david and lucy (a drone): a team that is not the paper's
TEAM_ROBOTS = ("alice", "bob", "david", "lucy")


@dataclass
class Readback:
    """A recording as rerun-sdk reads it back: each entity's rows (column -> value), and the blueprint's views."""

    rows: dict[str, list[dict[str, Any]]] = field(default_factory=lambda: defaultdict(list))
    static: set[str] = field(default_factory=set)
    views: list[tuple[str, str]] = field(default_factory=list)  # (class, origin)

    def texts(self, entity: str) -> list[str]:
        return [t for r in self.rows[entity] for t in (r.get("TextLog:text") or [])]

    def ticks(self, entity: str) -> list[int]:
        return [r["tick"] for r in self.rows[entity] if r.get("tick") is not None]


def rows_of(chunk: Any) -> list[dict[str, Any]]:
    """A chunk's rows, its time columns (log_time, sim_time) as integer nanoseconds."""
    batch = chunk.to_record_batch()
    for name, kind in zip(batch.schema.names, batch.schema.types):
        if str(kind).startswith(("timestamp", "duration")):
            batch = batch.set_column(batch.schema.get_field_index(name), name, batch.column(name).cast("int64"))
    return list(batch.to_pylist())


def read_back(path: Path) -> Readback:
    import rerun as rr

    out = Readback()
    reader = rr.chunk.RrdReader(str(path))
    for chunk in reader.stream():
        if chunk.entity_path.startswith("/__properties"):
            continue  # the recording's start time
        out.rows[chunk.entity_path].extend(rows_of(chunk))
        if chunk.is_static:
            out.static.add(chunk.entity_path)
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            for row in rows_of(chunk):
                if row.get("ViewBlueprint:class_identifier"):
                    out.views.append((row["ViewBlueprint:class_identifier"][0], row["ViewBlueprint:space_origin"][0]))
    return out


def verify(path: Path) -> None:
    """`rerun rrd verify`, the CLI rerun-sdk ships (with Rerun's analytics off)."""
    from mhrc.viewer.rerun.sinks import quiet_env, rerun_binary

    done = subprocess.run(
        [str(rerun_binary()), "rrd", "verify", str(path)], capture_output=True, text=True, env=quiet_env(), timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]


def done_of(trace: Path) -> EpisodeDone:
    return messages(read_records(trace), EpisodeDone)[-1]


@pytest.fixture(scope="module")
def episode(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One heuristic episode of a four-robot team with a drone, run by `mhrc up --rerun` (live), and the
    recording `mhrc show --rerun` makes from its trace."""
    d = tmp_path_factory.mktemp("rerun")
    trace, live, replayed = d / "trace.jsonl", d / "live.rrd", d / "from_trace.rrd"
    up = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--insecure", "-q", "--team", TEAM, "--objects", "3", "--horizon", "8"]
        + ["--trace", str(trace), "--rerun", str(live)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert up.returncode == 0, up.stderr[-3000:]
    assert f"rerun: {live}" in up.stderr and "dropped" not in up.stderr, up.stderr
    shown = CliRunner().invoke(main, ["show", str(trace), "--rerun", str(replayed)])
    assert shown.exit_code == 0, shown.output
    assert shown.output.strip().splitlines()[-1] == str(replayed)
    return {"trace": trace, "live": live, "from_trace": replayed}


@pytest.mark.parametrize("which", ["live", "from_trace"])
def test_a_recording_passes_rerun_verify_and_holds_the_episode(episode: dict[str, Path], which: str) -> None:
    path = episode[which]
    verify(path)
    got = read_back(path)
    done = done_of(episode["trace"])
    layout = get_layout("kitchen")
    # the house: walls and every piece of furniture, static; containers' state over time
    assert {"/world/walls", "/world/goal_area"} <= got.static
    assert {f"/world/furniture/{f.name}" for f in layout.furniture} <= got.static
    assert any(p.endswith("/state") for p in got.rows)
    # each robot: its body, its pose on the tick timeline from tick 0 to the end, its text logs
    ts = done.metrics.temporal_steps
    for robot in TEAM_ROBOTS:
        assert f"/world/robots/{robot}/body" in got.static
        ticks = got.ticks(f"/world/robots/{robot}")
        assert ticks and min(ticks) == 0 and max(ticks) <= ts
        assert got.texts(f"/agents/{robot}/thought") and got.texts(f"/agents/{robot}/outcome")
        assert got.texts(f"/agents/{robot}/action")
    assert max(t for r in TEAM_ROBOTS for t in got.ticks(f"/world/robots/{r}")) == ts
    # the drone flies at its altitude, the others roll on the floor
    lucy = [r["Transform3D:translation"][0] for r in got.rows["/world/robots/lucy"]]
    tallest = max(f.size[2] for f in layout.furniture)
    assert {round(p[2], 3) for p in lucy} == {flight_altitude(KINDS["drone"], tallest)}
    assert {p[2] for r in got.rows["/world/robots/david"] for p in r["Transform3D:translation"]} == {0.0}
    # objects where the world has them, where each robot believes them; messages; events
    objects = {name for r in got.rows["/world/objects"] for name in r["Points3D:labels"]}
    assert set(done.targets) <= objects
    assert got.rows["/world/beliefs/alice"] and got.texts("/messages")
    assert any("episode done" in t for t in got.texts("/events"))
    # progress: the last placed count and PS are the episode's
    placed = got.rows["/progress/placed"]
    last = max(placed, key=lambda r: r["tick"])
    assert last["Scalars:scalars"] == [float(done.metrics.placed)]
    last_ps = max(got.rows["/progress/ps"], key=lambda r: r["tick"])["Scalars:scalars"][0]
    assert last_ps == pytest.approx(done.metrics.partial_success)
    # the blueprint: the 3D view of the house, a text panel per robot, the progress plot
    assert ("3D", "world") in got.views and ("TimeSeries", "progress") in got.views
    assert {("TextLog", f"agents/{r}") for r in TEAM_ROBOTS} <= set(got.views)


def test_the_live_recording_and_the_one_from_the_trace_hold_the_same_entities(episode: dict[str, Path]) -> None:
    live, replayed = read_back(episode["live"]), read_back(episode["from_trace"])
    assert set(live.rows) == set(replayed.rows)
    for entity in ("/agents/alice/thought", "/agents/bob/outcome", "/messages"):
        assert sorted(live.texts(entity)) == sorted(replayed.texts(entity))


REPLIES = {
    "alice": ["Analysis: rerun-check-alice, I go to table_1 first.\nCommand: navigate(table_1, 0)"],
    "bob": ['Analysis: rerun-check-bob, I tell Alice.\nCommand: communicate("Alice, fetch the book", alice)'],
    "david": ["Analysis: rerun-check-david, I wait.\nCommand: wait()"],
}


def test_the_model_reply_is_in_the_live_recording_of_a_scripted_episode(tmp_path: Path) -> None:
    usage = {"prompt_tokens": 11, "completion_tokens": 7}
    script = {r: [ModelReply(t, usage=usage) for t in texts] for r, texts in REPLIES.items()}
    server = ScriptedModelServer(script, when_done=ModelReply("Analysis: done.\nCommand: wait()", usage=usage))
    out = tmp_path / "scripted.rrd"
    try:
        cfg = EpisodeConfig.build(
            seed=0, horizon=2, n_objects=3, llm="openai:test-model", base_url=server.url, trace=tmp_path / "t.jsonl"
        ).resolved()
        from mhrc.viewer.rerun.live import LiveRecording

        live = LiveRecording(Target(Mode.FILE, out), cfg.run)
        try:
            asyncio.run(up_in_process(cfg, observe=live.observe))
        finally:
            stats = live.close()
    finally:
        server.close()
    assert stats.dropped == 0 and stats.logged == stats.queued > 0 and not stats.warnings
    verify(out)
    got = read_back(out)
    for robot, texts in REPLIES.items():
        assert texts[0] in got.texts(f"/agents/{robot}/thought")
    assert any("Alice, fetch the book" in t for t in got.texts("/messages"))


def test_a_truncated_or_older_trace_gives_a_recording_of_what_can_be_read(
    episode: dict[str, Path], tmp_path: Path
) -> None:
    text = episode["trace"].read_text(encoding="utf-8")
    cut = tmp_path / "cut.jsonl"
    cut.write_text(text[: len(text) // 2], encoding="utf-8")
    old = as_version_1(episode["trace"], tmp_path / "v1.jsonl")
    for trace, said in ((cut, "truncated"), (old, "no snapshot")):
        report = CliRunner().invoke(main, ["show", str(trace), "--out", str(tmp_path / "r.html")])
        recording = CliRunner().invoke(main, ["show", str(trace), "--rerun", str(trace.with_suffix(".rrd"))])
        assert recording.exit_code == 0, recording.output
        warning = [ln for ln in recording.output.splitlines() if ln.startswith("mhrc show: warning:")]
        assert warning == [ln for ln in report.output.splitlines() if ln.startswith("mhrc show: warning:")]
        assert said in warning[0]
        verify(trace.with_suffix(".rrd"))
        got = read_back(trace.with_suffix(".rrd"))
        assert got.ticks("/world/robots/alice") and got.texts("/agents/alice/thought")
    assert not read_back(old.with_suffix(".rrd")).rows["/world/objects"]  # a version-1 trace has no objects


def test_an_unwritable_rerun_path_is_one_line_and_exit_2_before_the_episode(tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x", encoding="utf-8")
    trace = tmp_path / "never.jsonl"
    for args in (
        ["up", "--insecure", "--trace", str(trace), "--rerun", str(blocker / "x.rrd")],
        ["show", str(trace), "--rerun", str(blocker / "x.rrd")],
        ["up", "--insecure", "--trace", str(trace), "--rerun", str(tmp_path / "x.txt")],
        ["eval", "--out", str(tmp_path / "eval"), "--rerun", str(blocker / "recordings")],
    ):
        result = CliRunner().invoke(main, args)  # the option is checked as it is parsed: nothing has started
        assert result.exit_code == 2, result.output
        errors = [ln for ln in result.output.splitlines() if ln.startswith("Error:")]
        assert len(errors) == 1 and "--rerun" in errors[0] and "Traceback" not in result.output
        assert not trace.exists() and not (tmp_path / "x.txt").exists() and not (tmp_path / "eval").exists()


def test_without_rerun_sdk_rerun_says_how_to_install_it(tmp_path: Path) -> None:
    no_rerun = "import sys; sys.modules['rerun'] = None; from mhrc.cli import main; main()"
    result = subprocess.run(
        [sys.executable, "-c", no_rerun, "up", "--insecure", "--rerun", str(tmp_path / "x.rrd")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1 and "pip install 'mhrc[rerun]'" in errors[0], result.stderr


@pytest.mark.slow
def test_rerun_serve_serves_the_web_viewer_on_loopback(episode: dict[str, Path]) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mhrc", "show", str(episode["trace"]), "--rerun", "serve"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "CI": "1"},
    )
    try:
        assert proc.stderr is not None
        address = ""
        for line in proc.stderr:
            if line.startswith("rerun: serving "):
                address = line.split()[2]
                break
        assert address.startswith("http://127.0.0.1:"), address
        with urllib.request.urlopen(address, timeout=30) as page:
            assert page.status == 200 and b"rerun" in page.read().lower()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    assert proc.returncode == 0


@pytest.mark.slow
def test_eval_writes_one_recording_per_episode_at_its_traces_place(tmp_path: Path) -> None:
    out, recordings = tmp_path / "eval", tmp_path / "recordings"
    result = subprocess.run(
        [sys.executable, "-m", "mhrc", "eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3"]
        + ["--trials", "2", "--horizon", "4", "--workers", "1", "--out", str(out), "--rerun", str(recordings)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text(encoding="utf-8").splitlines()]
    made = sorted(recordings.rglob("*.rrd"))
    assert made == sorted((recordings / r["trace"]).with_suffix(".rrd") for r in rows) and len(made) == 2
    for path in made:
        verify(path)
        assert read_back(path).texts("/agents/bob/thought")
