"""examples/raw_zenoh_agent.py (raw zenoh + json, no mhrc import) drives David in a real
episode as a separate process, beside the heuristic Alice and Bob, in both stepped schedules."""

from __future__ import annotations

import ast
import asyncio
import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
from sweep import sweep

from mhrc.core import protocol
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "raw_zenoh_agent.py"


def test_schema_command_writes_every_payload(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "mhrc", "schema", "--out", str(tmp_path / "s")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    index = json.loads((tmp_path / "s" / "index.json").read_text())
    names = {
        m.__name__
        for m in vars(protocol).values()
        if isinstance(m, type) and issubclass(m, protocol.Message) and m is not protocol.Message
    }
    assert names | {"WorldEvent"} == set(index["payloads"])
    assert index["payloads"]["Turn"]["key"] == "mhrc/<run>/robot/<rid>/turn"
    assert index["payloads"]["AttachRequest"]["key"] == "mhrc/<run>/robot/<rid>/attach"
    for name, entry in index["payloads"].items():
        jsonschema.Draft202012Validator.check_schema(json.loads((tmp_path / "s" / entry["file"]).read_text()))
    printed = subprocess.run([sys.executable, "-m", "mhrc", "schema"], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0 and set(json.loads(printed.stdout)["schemas"]) == set(index["payloads"])


def test_example_imports_nothing_of_mhrc() -> None:
    tree = ast.parse(EXAMPLE.read_text(encoding="utf-8"))
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {(n.module or "").split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert "zenoh" in imported and "json" in imported
    assert not {m for m in imported if m.startswith("mhrc")}


@pytest.mark.parametrize("schedule", sweep(["lockstep", "sequential"]))
async def test_raw_zenoh_agent_plays_david(tmp_path: Path, schedule: str) -> None:
    trace_path = tmp_path / "t.jsonl"
    cfg = EpisodeConfig.build(seed=0, n_objects=3, horizon=30, schedule=schedule, trace=trace_path).resolved()
    world = asyncio.create_task(
        up_in_process(cfg, robots=("alice", "bob"))
    )  # the world and the heuristic Alice and Bob
    cmd = [
        sys.executable,
        str(EXAMPLE),
        "--connect",
        cfg.endpoint,
        "--run",
        cfg.run,
        "--robot",
        "david",
        "--step-timeout",
        "120",
    ]
    david = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        done = await asyncio.wait_for(world, 240)
        out, err = await asyncio.to_thread(david.communicate, timeout=60)
    finally:
        if not world.done():
            world.cancel()
            await asyncio.gather(world, return_exceptions=True)
        if david.poll() is None:
            david.kill()
            david.wait()
    assert done.reason in ("success", "horizon")
    assert david.returncode == 0, err
    assert f"episode_done reason={done.reason}" in out

    trace = read_records(trace_path)
    msgs = [(line.key.split("/", 2)[2], line.msg) for line in trace if line.msg is not None]
    requests = [m for k, m in msgs if k == "robot/david/action/request" and isinstance(m, protocol.ActionRequest)]
    acks = [m for k, m in msgs if k == "robot/david/action/ack" and isinstance(m, protocol.ActionAck)]
    results = [m for k, m in msgs if k == "robot/david/action/result" and isinstance(m, protocol.ActionResult)]
    assert requests and all("-raw-" in m.agent_id for m in requests), "David's requests did not come from the example"
    assert not [a for a in acks if not a.accepted and a.code is protocol.RejectCode.MALFORMED]
    assert [r for r in results if r.action.skill == "navigate"], "the example never navigated"
    assert any(k.startswith("robot/alice/inbox/david") for k, _ in msgs), "the example never reported to Alice"
    assert done.metrics.action_steps_per_robot["david"] > 0
    schema = json.loads(
        subprocess.run([sys.executable, "-m", "mhrc", "schema"], capture_output=True, text=True, timeout=60).stdout
    )["schemas"]
    for req in requests:  # what the example wrote from the docs is what the schema says
        jsonschema.validate(req.model_dump(mode="json"), schema["ActionRequest"])
    for result in results:
        jsonschema.validate(result.model_dump(mode="json"), schema["ActionResult"])
    started = next(m for k, m in msgs if isinstance(m, protocol.EpisodeStarted))
    assert started.scheduler == schedule
