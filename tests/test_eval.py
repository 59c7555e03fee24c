"""`mhrc eval`, `mhrc worker` and `mhrc report` over real worker processes, a real Zenoh bus on
loopback and real episodes (heuristic policy)."""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from mhrc.bus import endpoint, free_port
from mhrc.episode import ConfigError
from mhrc.evaluation import EvalSpec, evaluate, merge_runs, summary_markdown

SMALL = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=2)
VOLATILE = {"wall_time", "worker"}


def _rows(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (path / "episodes.jsonl").read_text().splitlines()]


def _stable(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {r["key"]: {k: v for k, v in r.items() if k not in VOLATILE} for r in rows}


def test_the_same_grid_twice_gives_the_same_metrics_and_resume_skips_finished_work(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    rows_a = asyncio.run(evaluate(SMALL, a, workers=2))
    rows_b = asyncio.run(evaluate(SMALL, b, workers=1))
    assert len(rows_a) == 2 and _stable(rows_a) == _stable(rows_b)
    assert all(r["success"] and r["lower_bound"] <= r["temporal_steps"] for r in rows_a)
    for r in rows_a:
        assert (a / r["trace"]).exists()
    summary = (a / "summary.md").read_text()
    assert "Table I" in summary and "| pack_objects | 1.00 / 1.00 /" in summary and "does not say" in summary
    assert (a / "summary.csv").read_text().startswith("method,ablation,task,episodes,succ,ps,ts,ts_bound,as,as_per_robot")
    # an existing directory is never overwritten by accident
    with pytest.raises(ConfigError, match="not empty; pass --resume"):
        asyncio.run(evaluate(SMALL, a, workers=1))
    # interrupted after one episode (and a torn last line): --resume runs only the missing one, plus a new trial
    c = tmp_path / "c"
    shutil.copytree(a, c)
    first = (c / "episodes.jsonl").read_text().splitlines()[0]
    (c / "episodes.jsonl").write_text(first + "\n" + '{"key": "pack_obj')
    more = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=3)
    rows_c = asyncio.run(evaluate(more, c, workers=1, resume=True))
    assert sorted(r["key"] for r in rows_c) == ["pack_objects/kitchen/3/0", "pack_objects/kitchen/3/1", "pack_objects/kitchen/3/2"]
    assert json.loads(first) in rows_c  # the finished row is kept as it was
    assert _stable(rows_c)[json.loads(first)["key"]] == _stable(rows_a)[json.loads(first)["key"]]
    with pytest.raises(ConfigError, match="--resume needs the same"):
        asyncio.run(evaluate(EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=2, ablation="no_mobile"), c, resume=True))
    # mhrc report merges directories into one table
    merged = merge_runs([a, b])
    assert len(merged) == 4 and "| heuristic | none | kitchen |" in summary_markdown(merged) and "| 4 |" in summary_markdown(merged)
    out = subprocess.run([sys.executable, "-m", "mhrc", "report", str(a), str(b), "--out", str(tmp_path / "r.md")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "Table I" in out.stdout and (tmp_path / "r.csv").exists()
    bad = subprocess.run([sys.executable, "-m", "mhrc", "report", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "no episodes.jsonl" in bad.stderr


def test_workers_on_other_processes_join_over_the_bus(tmp_path: Path) -> None:
    listen = endpoint("127.0.0.1", free_port("127.0.0.1"))
    cmd = [sys.executable, "-m", "mhrc", "eval", "--tasks", "sort_solids", "--scenes", "bedroom", "--objects", "3", "--trials", "3",
           "--workers", "0", "--listen", listen, "--out", str(tmp_path / "ev")]  # fmt: skip
    coordinator = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    workers = [
        subprocess.Popen([sys.executable, "-m", "mhrc", "worker", "--connect", listen], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    try:
        out, err = coordinator.communicate(timeout=240)
        assert coordinator.returncode == 0, err
        ran = []
        for w in workers:
            _, werr = w.communicate(timeout=60)
            assert w.returncode == 0, werr
            ran.append(int(werr.split("worker ran ")[1].split()[0]))
        assert sum(ran) == 3
        rows = _rows(tmp_path / "ev")
        assert len(rows) == 3 and all(r["success"] for r in rows) and len({r["worker"] for r in rows}) == sum(1 for n in ran if n)
        assert "| sort_solids |" in out
    finally:
        for p in (coordinator, *workers):
            if p.poll() is None:
                p.kill()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--tasks", "juggle"], "unknown task 'juggle'"),
        (["--objects", "3,9"], "n_objects"),
        (["--scenes", "castle"], "unknown scene 'castle'"),
        (["--trials", "0"], "trials: must be at least 1"),
        (["--workers", "0"], "--workers 0 needs --listen"),
    ],
)
def test_bad_eval_options_fail_before_anything_starts(tmp_path: Path, args: list[str], message: str) -> None:
    out = subprocess.run([sys.executable, "-m", "mhrc", "eval", "--out", str(tmp_path / "x"), *args], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and message in out.stderr, out.stderr
    assert not (tmp_path / "x").exists()


GRABBER = """
import asyncio, sys
from mhrc.episode import open_client
from mhrc.evaluation import JobRequest, JobReply, find_eval
from mhrc.protocol import decode

async def main():
    bus = await open_client(sys.argv[1], 60.0)  # retries while the coordinator starts
    try:
        eid = await find_eval(bus)
        bus.declare_token(f"mhrc/eval/{eid}/alive/worker/grabber")
        reply = decode((await bus.get(f"mhrc/eval/{eid}/job", JobRequest(worker="grabber")))[0], JobReply)
        print(reply.job.key if reply.job else "none", flush=True)
        await asyncio.sleep(3600)  # takes the job and never finishes it
    finally:
        await bus.close()

asyncio.run(main())
"""


def test_a_job_whose_worker_dies_goes_to_another_worker(tmp_path: Path) -> None:
    listen = endpoint("127.0.0.1", free_port("127.0.0.1"))
    cmd = [sys.executable, "-m", "mhrc", "eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3", "--trials", "1",
           "--workers", "0", "--listen", listen, "--out", str(tmp_path / "ev")]  # fmt: skip
    coordinator = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    grabber = subprocess.Popen([sys.executable, "-c", GRABBER, listen], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    worker = None
    try:
        assert grabber.stdout is not None
        assert grabber.stdout.readline().strip() == "pack_objects/kitchen/3/0"  # the only job is taken
        grabber.kill()  # ... and its worker dies with it
        grabber.wait(timeout=10)
        worker = subprocess.Popen([sys.executable, "-m", "mhrc", "worker", "--connect", listen], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _, err = coordinator.communicate(timeout=120)
        assert coordinator.returncode == 0, err
        rows = _rows(tmp_path / "ev")
        assert [r["key"] for r in rows] == ["pack_objects/kitchen/3/0"] and rows[0]["worker"] != "grabber" and rows[0]["success"]
        _, werr = worker.communicate(timeout=60)
        assert "worker ran 1 episode(s)" in werr
    finally:
        for p in (coordinator, grabber, worker):
            if p is not None and p.poll() is None:
                p.kill()
