"""Videos rendered from a real episode's trace (heuristic team, real Zenoh on loopback, real PyBullet)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from mhrc.core.protocol import Snapshot
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.viewer.video import TraceWithoutSnapshots, UnsupportedVideoFormat, read_episode, render_video
from mhrc.world.sim import Sim

HORIZON = 3
FRAMES_PER_STEP = 2
W, H = 320, 240


@pytest.fixture(scope="module")
def trace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("video") / "trace.jsonl"
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, n_objects=6, horizon=HORIZON, trace=path).resolved()))
    return path


def _frames(path: Path) -> list[np.ndarray]:
    return [f[:, :, :3] for f in iio.imiter(path)]


def _snapshots(trace: Path) -> list[Snapshot]:
    lines = [json.loads(line) for line in trace.read_text().splitlines()]
    return [Snapshot.model_validate(x["msg"]) for x in lines if (x["msg"] or {}).get("kind") == "snapshot"]


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_video_has_a_frame_per_step_and_shows_the_robots_moving(trace: Path, tmp_path: Path, suffix: str) -> None:
    seen: list[tuple[int, int]] = []
    out = tmp_path / f"episode{suffix}"
    info = render_video(
        trace,
        out,
        width=W,
        height=H,
        frames_per_step=FRAMES_PER_STEP,
        progress=lambda n, total: seen.append((n, total)),
    )
    steps = HORIZON + 1  # the start, then one batch per tick
    assert info.steps == steps and info.frames == steps * FRAMES_PER_STEP
    assert out.exists() and info.bytes == out.stat().st_size > 0
    assert seen == [(n, info.frames) for n in range(1, info.frames + 1)]
    frames = _frames(out)
    assert len(frames) == info.frames
    assert all(f.shape == (H, W, 3) for f in frames)
    picture = H // 2  # the upper half is scene only; the captions lie below it
    first, last = frames[0][:picture].astype(int), frames[-1][:picture].astype(int)
    assert np.abs(first - last).max() > 60  # somebody moved across the house


def test_captions_name_each_robots_action_and_outcome(trace: Path) -> None:
    started, steps, _ = read_episode(trace)
    assert [c.robot for c in steps[0].captions] == started.robots and all(
        c.succeeded is None for c in steps[0].captions
    )
    acted = [c for s in steps[1:] for c in s.captions]
    assert len(acted) == HORIZON * len(started.robots)
    assert all(c.succeeded is not None and ("-> ok" in c.text or "-> FAILED" in c.text) for c in acted)
    assert any(c.text.startswith("navigate(") for c in acted)


def test_apply_snapshot_puts_bodies_where_the_trace_says(trace: Path) -> None:
    started, _, _ = read_episode(trace)
    last = _snapshots(trace)[-1]
    with Sim(task=started.task, scene=started.scene, seed=started.seed, n_objects=started.n_objects) as sim:
        before = sim.poses()[0]
        sim.apply_snapshot(last.robots, last.objects, last.open)
        robots, objects, opened = sim.poses()
    assert any((before[r].x, before[r].y) != (last.robots[r].x, last.robots[r].y) for r in robots)
    for name, rp in last.robots.items():
        assert (robots[name].x, robots[name].y, robots[name].holding) == pytest.approx(
            (rp.x, rp.y, rp.holding), abs=1e-3
        )
    for name, op in last.objects.items():
        got = objects[name]
        assert (got.x, got.y, got.held_by, got.on) == pytest.approx((op.x, op.y, op.held_by, op.on), abs=2e-3)
        if op.held_by is None:
            assert got.z == pytest.approx(op.z, abs=2e-3)
    assert opened == last.open


def test_unsupported_suffix_names_the_supported_ones(trace: Path, tmp_path: Path) -> None:
    out = tmp_path / "episode.avi"
    with pytest.raises(UnsupportedVideoFormat, match=r"\.mp4, \.gif") as exc:
        render_video(trace, out)
    assert isinstance(exc.value, ValueError) and not out.exists()


def test_trace_from_before_snapshots_is_refused(trace: Path, tmp_path: Path) -> None:
    old = tmp_path / "old.jsonl"
    old.write_text("".join(line + "\n" for line in trace.read_text().splitlines() if '"kind":"snapshot"' not in line))
    with pytest.raises(TraceWithoutSnapshots, match="predates snapshots"):
        render_video(old, tmp_path / "old.mp4")
    assert not (tmp_path / "old.mp4").exists()
