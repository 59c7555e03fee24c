"""`mhrc eval` and `mhrc report` over real local worker processes (mhrc.eval.pool), real Zenoh
buses on loopback and real episodes (heuristic policy, and LLM agents against a scripted
OpenAI-compatible server on loopback). Ray: tests/test_ray_eval.py."""

from __future__ import annotations

import asyncio
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from json_rows import records
from pydantic import ValidationError
from waits import until_sync

from mhrc.core.endpoints import free_port
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.records import EvalRow, upgrade_row
from mhrc.eval.report import summary_markdown
from mhrc.eval.rows import merge_runs
from mhrc.run.config import ConfigError
from mhrc.testing import ModelReply, ScriptedModelServer

SMALL = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=2)
TINY_GRID = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,))  # one episode of the default grid
VOLATILE = {"wall_time", "worker"}


def _rows(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (path / "episodes.jsonl").read_text().splitlines()]


def _flat(rows: list[EvalRow]) -> list[dict[str, Any]]:
    """Rows as episodes.jsonl holds them."""
    return [dict(r.flat()) for r in rows]


def _stable(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {r["key"]: {k: v for k, v in r.items() if k not in VOLATILE} for r in rows}


@pytest.mark.slow
def test_the_same_grid_twice_gives_the_same_metrics_and_resume_skips_finished_work(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    rows_a = _flat(asyncio.run(evaluate(SMALL, a, workers=2)))
    rows_b = _flat(asyncio.run(evaluate(SMALL, b, workers=1)))
    assert len(rows_a) == 2 and _stable(rows_a) == _stable(rows_b)
    assert all(r["success"] and r["lower_bound"] <= r["temporal_steps"] for r in rows_a)
    for r in rows_a:
        assert (a / r["trace"]).exists()
    summary = (a / "summary.md").read_text()
    assert (
        "Table I" in summary and "| pack_objects | 1.00 / 1.00 /" in summary and "set beside the paper's AS" in summary
    )
    assert (
        (a / "summary.csv")
        .read_text()
        .startswith(
            "method,ablation,fidelity,noise,history_cap,horizon,mode,schedule,scenario,task,episodes,succ,ps,ts,ts_bound,as_ticks,as,as_per_robot"
        )
    )
    for r in rows_a:  # fidelity and the LLM failures are on every row (the heuristic has none)
        assert (r["fidelity"], r["aids"], r["history_cap"], r["horizon"], r["repeat"], r["trial"]) == (
            "paper",
            [],
            None,
            50,
            0,
            r["seed"],
        )
        assert (r["parse_failures"], r["llm_unreachable"], r["rejected_actions"], r["valid"], r["invalid_reason"]) == (
            0,
            0,
            0,
            True,
            None,
        )
    # an existing directory is never overwritten by accident
    with pytest.raises(ConfigError, match="not empty; pass --resume"):
        asyncio.run(evaluate(SMALL, a, workers=1))
    # interrupted after one episode (and a torn last line): --resume runs only the missing one, plus a new trial
    c = tmp_path / "c"
    shutil.copytree(a, c)
    first = (c / "episodes.jsonl").read_text().splitlines()[0]
    (c / "episodes.jsonl").write_text(first + "\n" + '{"key": "pack_obj')
    more = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=3)
    rows_c = _flat(asyncio.run(evaluate(more, c, workers=1, resume=True)))
    assert sorted(r["key"] for r in rows_c) == [
        "pack_objects/kitchen/3/0",
        "pack_objects/kitchen/3/1",
        "pack_objects/kitchen/3/2",
    ]
    assert json.loads(first) in rows_c  # the finished row is kept as it was
    assert _stable(rows_c)[json.loads(first)["key"]] == _stable(rows_a)[json.loads(first)["key"]]
    for other, differs in (
        ({"ablation": "no_mobile"}, "--ablation was 'none', now 'no_mobile'"),
        ({"aids": ("goal_map",)}, "--aids was 'paper', now 'aids:goal_map'"),
        ({"history_cap": 9000}, "--history-cap was None, now 9000"),
    ):
        with pytest.raises(ConfigError, match=f"holds another evaluation: {re.escape(differs)}$"):
            asyncio.run(
                evaluate(
                    EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=2, **other),
                    c,
                    resume=True,
                )
            )  # type: ignore[arg-type]
    # mhrc report merges directories into one table
    merged = merge_runs([a, b])
    # the intervals do not depend on the order the rows come in (the order workers finished in)
    spread = [
        upgrade_row(
            dict(merged[0].flat(), key=f"pack_objects/kitchen/3/{i}", seed=i, trace=None, temporal_steps=10 + i * i)
        )
        for i in range(12)
    ]
    assert summary_markdown(spread) == summary_markdown(spread[::-1])
    assert (
        len(merged) == 4
        and "| heuristic | none | paper | kitchen |" in summary_markdown(merged)
        and "| 4 |" in summary_markdown(merged)
    )
    out = subprocess.run(
        [sys.executable, "-m", "mhrc", "report", str(a), str(b), "--out", str(tmp_path / "r.md")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0 and "Table I" in (tmp_path / "r.md").read_text() and (tmp_path / "r.csv").exists()
    bad = subprocess.run(
        [sys.executable, "-m", "mhrc", "report", str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 2 and "no episodes.jsonl" in bad.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--tasks", "juggle"], "unknown task 'juggle'"),
        (["--objects", "3,9"], "--objects: Input should be less than or equal to 6"),
        (["--scenes", "castle"], "unknown scene 'castle'"),
        (["--trials", "0"], "--trials: must be at least 1"),
        (["--repeats", "0"], "--repeats: must be at least 1 (got 0)"),
        (["--repeats", "-2"], "--repeats: must be at least 1 (got -2)"),
        (["--aids", "crystal_ball"], "--aids: unknown aid 'crystal_ball'"),
        (["--history-cap", "0"], "--history-cap"),
        (["--workers", "0"], "--workers: must be at least 1 (got 0)"),
        (["--ray", "auto", "--workers", "2"], "--workers: not with --ray"),
        (["--shared-out"], "--shared-out: only with --ray"),
        (["--ray", f"127.0.0.1:{free_port('127.0.0.1')}"], "--ray: nothing answers at 127.0.0.1:"),
        (["--ray", "nowhere"], "--ray: 'nowhere' is not an address ray.init takes"),
        (["--listen", "tls/127.0.0.1:7448"], "No such option '--listen'"),  # the job queue is gone
        (["--credentials", "/tmp/creds"], "No such option '--credentials'"),
    ],
)
def test_bad_eval_options_fail_before_anything_starts(tmp_path: Path, args: list[str], message: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "mhrc", "eval", "--out", str(tmp_path / "x"), *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and message in out.stderr, out.stderr
    assert not (tmp_path / "x").exists()


def _pool_workers(parent: int) -> list[int]:
    """The pids of `parent`'s children that are local pool workers (python -m mhrc.eval.pool)."""
    out = []
    for status in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(status.read_text().rsplit(")", 1)[1].split()[1])
            cmd = (status.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == parent and b"mhrc.eval.pool" in cmd:
            out.append(int(status.parent.name))
    return out


@pytest.mark.slow
def test_an_episode_whose_worker_process_dies_runs_again_on_a_new_one(tmp_path: Path) -> None:
    """SIGKILL the only worker mid-episode (its trace has begun): the driver starts another
    worker, which runs the episode again; its row is there and no error is recorded."""
    import os
    import signal

    tmp = tmp_path / "tmp"
    tmp.mkdir()
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
        "--workers",
        "1",
        "--out",
        str(tmp_path / "ev"),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ, TMPDIR=str(tmp))
    )
    try:
        until_sync(
            lambda: any(p.stat().st_size for p in tmp.glob("mhrc-eval-*/trace.jsonl")),
            "an episode under way",
            120,
            every=0.05,
            running=proc,
            said=lambda: proc.communicate()[1][-2000:],
        )
        (victim,) = _pool_workers(proc.pid)
        os.kill(victim, signal.SIGKILL)
        _, err = proc.communicate(timeout=240)
        assert proc.returncode == 0, err[-2000:]
        rows = _rows(tmp_path / "ev")
        assert [r["key"] for r in rows] == ["pack_objects/kitchen/3/0"] and rows[0]["success"]
        assert rows[0]["worker"] != f"{os.uname().nodename}:{victim}"  # run again, by another process
        assert not (tmp_path / "ev" / "errors.jsonl").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# --------------------------------------------------------------------------- the paper's grid


def _dry_run(*args: str) -> list[tuple[str, int, int]]:
    """(key, repeat, seed) of every episode `mhrc eval --dry-run` lists."""
    from click.testing import CliRunner

    from mhrc.cli import main

    res = CliRunner().invoke(main, ["eval", "--dry-run", *args])
    assert res.exit_code == 0, res.output
    lines = [line.split() for line in res.output.splitlines() if "repeat=" in line]
    return [(k, int(r.split("=")[1]), int(s.split("=")[1])) for k, r, _t, s in lines]


def test_the_default_grid_is_the_papers_and_repeats_multiply_it_with_new_seeds() -> None:
    jobs = _dry_run()
    assert len(jobs) == 36 and len({k for k, _, _ in jobs}) == 36
    by_task: dict[str, list[str]] = {}
    for key, repeat, seed in jobs:
        by_task.setdefault(key.split("/")[0], []).append(key)
        assert (repeat, seed) == (0, 0)
    assert sorted(by_task) == ["make_sandwich", "pack_objects", "sort_solids"] and all(
        len(v) == 12 for v in by_task.values()
    )
    cells: dict[tuple[str, str], list[int]] = {}
    for key, _, _ in jobs:
        task, scene, n, _seed = key.split("/")
        cells.setdefault((task, scene), []).append(int(n))
    assert len(cells) == 9 and all(sorted(ns) == [3, 4, 5, 6] for ns in cells.values())  # one episode per object count

    twice = _dry_run("--repeats", "2")
    assert len(twice) == 72 and len({k for k, _, _ in twice}) == 72
    assert {(r, s) for _, r, s in twice} == {(0, 0), (1, 1)}  # repeat r runs with seed r
    assert [k for k, r, _ in twice if r == 0] == [k for k, _, _ in jobs]  # repeat 0 is the run without --repeats
    # explicit --objects and --trials build larger grids: every object count x trials, per repeat
    big = _dry_run(
        "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3,5", "--trials", "3", "--repeats", "2"
    )
    assert len(big) == 12 and sorted({s for _, _, s in big}) == [0, 1, 2, 3, 4, 5]

    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), repeats=2)
    assert [j.config.seed for j in spec.jobs()] == [0, 0, 0, 0, 1, 1, 1, 1]
    with pytest.raises(ConfigError, match="--repeats"):
        EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), repeats=0).validate()


def _put(kind: str, **msg: Any) -> dict[str, Any]:
    """A hand-built trace line, with the protocol's required fields the test leaves out filled in
    (test_metrics' helper: the trace reader decodes every message)."""
    from test_metrics import _put as put

    return put(kind, **msg)


def test_llm_failures_and_validity_are_counted_from_the_trace() -> None:
    from mhrc.agents.replay import LLM_ERROR_PREFIX
    from mhrc.analysis.metrics import from_trace

    def trace(*thoughts: str | None, fidelity: str | None = "aids:goal_map") -> list[dict[str, Any]]:
        started: dict[str, Any] = {
            "run": "r",
            "task": "pack_objects",
            "scene": "kitchen",
            "seed": 0,
            "n_objects": 3,
            "robots": ["bob"],
            "horizon": 4,
        }
        if fidelity is not None:
            started["fidelity"] = fidelity
        rows = [_put("episode_started", **started)]
        rows += [
            _put("thought", robot="bob", tick=i, policy="llm:m", prompt="p", parse_error=e)
            for i, e in enumerate(thoughts)
        ]
        rows += [
            _put("action_ack", goal_id="g1", robot="bob", accepted=False, reason="stale"),
            _put("action_ack", goal_id="g2", robot="bob", accepted=True),
        ]
        metrics = {"success": False, "placed": 0, "total": 3, "partial_success": 0.0}
        return rows + [_put("tick", tick=0), _put("episode_done", run="r", reason="horizon", metrics=metrics)]

    down = LLM_ERROR_PREFIX + "m at http://x failed after 5 attempts: HTTP 503"
    m = from_trace(records(trace(None, "no command in the reply", down, None)))
    assert (m.llm_calls, m.parse_failures, m.llm_unreachable, m.rejected_actions) == (4, 1, 1, 1)
    assert m.valid and m.invalid_reason is None and (m.fidelity, m.horizon) == ("aids:goal_map", 4)
    m = from_trace(records(trace(down, down, fidelity=None)))
    assert not m.valid and m.invalid_reason and "unreachable for all 2 LLM steps" in m.invalid_reason
    assert m.fidelity == "unrecorded"  # a trace from before episodes recorded their fidelity
    assert from_trace(records(trace())).valid  # no LLM step at all (the heuristic): valid


# --------------------------------------------------------------------------- LLM agents over HTTP


class ScriptedModel:
    """The model behind an OpenAI-compatible endpoint on loopback (a `ScriptedModelServer`).

    Episodes run one after the other (one worker), so a step number lower than the last one seen
    starts the next episode. In episode `down` the model never answers in time: every call
    outlasts the client's timeout, is retried once and lost (a server down from the first step
    would stop the run instead: tests/test_llm_bounds.py). Elsewhere Bob's first reply has no
    command (a parse failure) and every other reply is a wait."""

    def __init__(self, down: int) -> None:
        import threading

        self.down = down
        self.episode = 0
        self.last_step = -1
        self.lock = threading.Lock()
        self.server = ScriptedModelServer(self.answer, when_done=None)
        self.url = self.server.url

    def answer(self, body: dict[str, Any]) -> ModelReply:
        system = body["messages"][0]["content"]
        step = ScriptedModelServer.step_of(body)
        assert step is not None
        with self.lock:
            if step < self.last_step:
                self.episode += 1
            self.last_step = step
            episode = self.episode
        if episode == self.down:
            return ModelReply(
                status=503, body={"error": {"message": "too late"}}, latency=3600.0
            )  # never, in the test's time
        robot = system.split()[2].rstrip(",").lower()  # "You are Bob, ..."
        text = (
            "Let me think about the tray first."
            if robot == "bob" and step == 0
            else "Analysis: nothing to do yet.\nCommand: wait()"
        )
        return ModelReply(text, usage={"prompt_tokens": 50, "completion_tokens": 9})

    def close(self) -> None:
        self.server.close()


@pytest.mark.slow
def test_an_llm_evaluation_records_parse_failures_and_leaves_out_an_episode_the_model_never_answered(
    tmp_path: Path,
) -> None:
    model = ScriptedModel(down=1)  # the second episode (4 objects) never reaches the model
    spec = EvalSpec(
        tasks=("pack_objects",),
        scenes=("kitchen",),
        objects=(3, 4, 5),
        horizon=2,
        llm="openai:test-model",
        base_url=model.url,
        llm_timeout=0.5,
        aids=("goal_map",),
        history_cap=50_000,
    )
    try:
        rows = _flat(asyncio.run(evaluate(spec, tmp_path / "ev", workers=1)))
    finally:
        model.close()
    by_key = {r["key"]: r for r in rows}
    assert sorted(by_key) == ["pack_objects/kitchen/3/0", "pack_objects/kitchen/4/0", "pack_objects/kitchen/5/0"]
    for r in rows:  # the configuration the episode ran with is on its row
        assert (r["method"], r["fidelity"], r["aids"], r["history_cap"], r["horizon"]) == (
            "openai:test-model",
            "aids:goal_map",
            ["goal_map"],
            50_000,
            2,
        )
        assert (r["prompts"], r["base_url"]) == (
            None,
            model.url,
        )  # what says whether the paper's figures may stand beside it
        assert r["temporal_steps"] == 2 and r["llm_calls"] == 6  # three robots, two steps
    down = by_key["pack_objects/kitchen/4/0"]
    assert (down["llm_unreachable"], down["parse_failures"], down["prompt_tokens"], down["valid"]) == (6, 0, 0, False)
    assert "unreachable for all 6 LLM steps" in down["invalid_reason"]
    for key in ("pack_objects/kitchen/3/0", "pack_objects/kitchen/5/0"):
        r = by_key[key]
        assert (r["parse_failures"], r["llm_unreachable"], r["rejected_actions"], r["valid"]) == (1, 0, 0, True)
        assert (r["prompt_tokens"], r["completion_tokens"]) == (6 * 50, 6 * 9)
    summary = (tmp_path / "ev" / "summary.md").read_text()
    assert "3 episodes, 2 valid, 1 invalid" in summary and "1 invalid episode left out" in summary
    assert (
        "- pack_objects/kitchen/4/0 (openai:test-model · ablation none · aids:goal_map · history cap 50000 · horizon 2): the model was unreachable"
        in summary
    )
    assert "| pack_objects | 2 | 0.00 [0.00, 0.00] |" in summary  # only the two valid episodes are averaged
    assert "paper GPT" not in summary  # no model of the paper's
    csv_line = (tmp_path / "ev" / "summary.csv").read_text().splitlines()[1]
    assert csv_line.startswith(
        "openai:test-model,none,aids:goal_map,on,50000,2,free,sequential,,pack_objects,2,"
    )  # eval runs the paper's loop by default (no scenario), with the calibrated noise


def test_a_wrong_api_key_stops_the_evaluation_with_one_error_and_a_failing_exit(tmp_path: Path) -> None:
    """Not a grid of PS 0.00 rows and exit 0: the first episode's 401 stops the run."""
    from click.testing import CliRunner

    from mhrc.cli import main

    server = ScriptedModelServer(
        lambda body: ModelReply(status=401, body={"error": {"message": "Incorrect API key provided"}}), when_done=None
    )
    try:
        result = CliRunner().invoke(
            main,
            [
                "eval",
                "--llm",
                "openai:gpt-4o",
                "--base-url",
                server.url,
                "--tasks",
                "pack_objects",
                "--scenes",
                "kitchen",
                "--workers",
                "1",
                "--concurrency",
                "1",
                "--out",
                str(tmp_path / "ev"),
            ],
        )
    finally:
        server.close()
    assert result.exit_code == 1, result.output
    assert "refused the credentials (HTTP 401)" in result.output and "--resume" in result.output
    assert (
        not (tmp_path / "ev" / "episodes.jsonl").exists()
        or not (tmp_path / "ev" / "episodes.jsonl").read_text().strip()
    )
    assert len(server.requests) <= 6  # the first episode's robots (and at most one more episode's) asked once each


SMALL_ARGS = ["eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3", "--workers", "1"]


def _mhrc(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_eval_names_every_file_it_wrote_and_a_resume_counts_the_earlier_episodes(tmp_path: Path) -> None:
    first = _mhrc(*SMALL_ARGS, "--out", "ev", cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    last = first.stderr.strip().splitlines()[-1]
    written = ["episodes.jsonl", "summary.md", "summary.csv", "summary.html"]
    assert last.startswith("done in") and all(str(Path("ev") / name) in last for name in written), last
    assert all((tmp_path / "ev" / name).exists() for name in written)
    # stderr is a pipe (as in CI, nohup, | tee): one line per finished episode, its key, result, TS and count
    (row,) = _rows(tmp_path / "ev")
    result = "solved" if row["success"] else f"not solved (PS {row['partial_success']:.2f})"
    assert f"\npack_objects/kitchen/3/0: {result}, TS {row['temporal_steps']} (1/1)\n" in first.stderr, first.stderr
    assert "1 worker," in first.stderr and "(s)" not in first.stderr
    # a resume of the finished grid: the totals are the grid's, not "0/0"
    again = _mhrc(*SMALL_ARGS, "--out", "ev", "--resume", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "[1/1 solved (all from before)]" in again.stderr and "0/0" not in again.stderr, again.stderr[-2000:]
    # mhrc report --out: the markdown goes to the file, the files written are named on stderr
    rep = _mhrc("report", "ev", "--out", "r.md", cwd=tmp_path)
    assert rep.returncode == 0 and rep.stdout == "", (rep.stdout[:500], rep.stderr)
    assert rep.stderr.strip() == "wrote r.md, r.csv, r.html" and "Table I" in (tmp_path / "r.md").read_text()
    assert (tmp_path / "r.csv").exists() and (tmp_path / "r.html").exists()
    assert "Table I" in _mhrc("report", "ev", cwd=tmp_path).stdout  # without --out, on stdout
    for bad in ("/dev/null/r.md", "r.csv"):  # not writable; overwritten by the CSV beside it
        refused = _mhrc("report", "ev", "--out", bad, cwd=tmp_path)
        assert (
            refused.returncode == 2
            and "Error: Invalid value for --out" in refused.stderr
            and "Traceback" not in refused.stderr
        ), refused.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ev", "r.csv", "r.html", "r.md"]


@pytest.mark.slow
def test_a_second_ctrl_c_on_eval_quits_at_once_and_loses_no_row(tmp_path: Path) -> None:
    """The first Ctrl-C stops the workers; the second, while they stop, quits at once, skipping
    every `finally`: the rows written stay whole, and no worker process outlives the driver."""
    import os
    import signal

    err = tmp_path / "stderr.txt"
    with err.open("w") as stderr:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "mhrc",
                "eval",
                "--tasks",
                "pack_objects",
                "--scenes",
                "kitchen",
                "--objects",
                "3,4,5,6",
                "--workers",
                "2",
                "--out",
                "ev",
            ],
            cwd=tmp_path,
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            text=True,
            start_new_session=True,
        )  # fmt: skip  (a session of its own: the signals go to its group, as a terminal's Ctrl-C)

    def until(what: str, predicate: Any) -> None:  # the finally below kills the evaluation if it never comes
        until_sync(predicate, what, 240, every=0.02, running=proc, said=lambda: err.read_text()[-2000:])

    rows = tmp_path / "ev" / "episodes.jsonl"
    try:
        until("first episode", lambda: rows.exists() and rows.read_text().endswith("\n"))
        workers = _pool_workers(proc.pid)
        before = rows.read_text()
        os.killpg(proc.pid, signal.SIGINT)
        until("'interrupted' line", lambda: "interrupted: stopping the workers" in err.read_text())
        os.killpg(proc.pid, signal.SIGINT)  # while the workers stop
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = err.read_text()
    assert "quitting at once" in text and proc.returncode == 130, (proc.returncode, text[-2000:])
    after = rows.read_text()
    assert after.startswith(before) and after.endswith("\n"), "a finished row was lost or cut"
    until_sync(  # the workers die with the driver (mhrc.core.lifeline)
        lambda: not [pid for pid in workers if _running(pid)], f"worker processes {workers} gone", 60, every=0.05
    )


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def test_a_metric_added_to_the_metrics_reaches_the_file_and_comes_back_declared_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A row holds the one EpisodeMetrics (and the one Diagnostics): a field added there, and
    nowhere else, is a column of episodes.jsonl, in the metrics' place, and is read back into the
    row's metrics; the default grid's columns keep their order around it."""
    from pydantic import create_model

    from mhrc.analysis.diagnostics import Diagnostics
    from mhrc.analysis.metrics import EpisodeMetrics
    from mhrc.analysis.values import Count
    from mhrc.eval import records

    before = dict(_flat(asyncio.run(evaluate(TINY_GRID, tmp_path / "ev", workers=1)))[0])
    metrics: Any = create_model("EpisodeMetrics", __base__=EpisodeMetrics, handoffs=(Count, 0))
    diagnostics: Any = create_model("Diagnostics", __base__=Diagnostics, stalls=(Count, 0))
    row: Any = create_model(
        "EvalRow", __base__=records.EvalRow, metrics=(metrics, ...), diagnostics=(diagnostics | None, None)
    )
    for name, model in (("EpisodeMetrics", metrics), ("Diagnostics", diagnostics), ("EvalRow", row)):
        monkeypatch.setattr(records, name, model)
    flat = {**before, "handoffs": 4, "diag_stalls": 2}
    read = records.upgrade_row(flat)
    assert (read.metrics.handoffs, read.diagnostics.stalls) == (4, 2) and not read.model_extra
    columns = list(read.flat())
    assert columns.index("redundant_per_robot") + 1 == columns.index("handoffs") == columns.index("aids") - 1
    assert columns[-1] == "diag_stalls" and read.flat() == {k: flat[k] for k in columns}
    (tmp_path / "x.jsonl").write_text(read.line())
    (again,) = records.read_rows(tmp_path / "x.jsonl")
    assert again == read and again.line() == read.line()
    with pytest.raises(ValidationError):  # the new metric has its range, as every other
        records.upgrade_row({**flat, "handoffs": -1})
