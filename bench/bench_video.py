"""Rendering an episode's video from its trace (mhrc.viewer.video).

Runs one heuristic episode in-process (Pack Objects, kitchen, seed 0, 6 objects by default),
records its trace, then renders it to .mp4 with PyBullet's CPU renderer and reports the
frame count, rendering seconds per frame, the whole job's seconds and the file size. With
--frame, the middle frame is also written as a PNG. Prints JSON (and writes it with --out).

    python bench/bench_video.py [--seed 0] [--objects 6] [--frames-per-step 4] [--frame /tmp/video_mid.png] [--out bench/results/video.json]
"""

from __future__ import annotations

import argparse
import asyncio
import platform
import tempfile
import time
from pathlib import Path

import imageio.v3 as iio
from report import emit

from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.viewer.video import FPS, render_video


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="pack_objects")
    ap.add_argument("--scene", default="kitchen")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--frames-per-step", type=int, default=4)
    ap.add_argument("--frame", type=Path, default=None, help="write the video's middle frame here (PNG)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench_video_") as tmp:
        trace, video = Path(tmp) / "trace.jsonl", Path(tmp) / "episode.mp4"
        cfg = EpisodeConfig.build(
            task=args.task, scene=args.scene, seed=args.seed, n_objects=args.objects, trace=trace
        ).resolved()
        t0 = time.perf_counter()
        done = asyncio.run(up_in_process(cfg))
        episode_s = time.perf_counter() - t0
        info = render_video(trace, video, width=args.width, height=args.height, frames_per_step=args.frames_per_step)
        frames = iio.imread(video, index=None)
        if args.frame is not None:
            args.frame.parent.mkdir(parents=True, exist_ok=True)
            iio.imwrite(args.frame, frames[len(frames) // 2])

    emit(
        {
            "benchmark": "video",
            "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
            "episode": {
                "task": args.task,
                "scene": args.scene,
                "seed": args.seed,
                "n_objects": args.objects,
                "reason": done.reason,
                "temporal_steps": done.metrics.temporal_steps,
                "wall_s": round(episode_s, 3),
            },
            "video": {
                "format": "mp4 (H.264, imageio-ffmpeg)",
                "width": info.width,
                "height": info.height,
                "fps": FPS,
                "frames_per_step": args.frames_per_step,
                "snapshots": info.steps,
                "frames": info.frames,
                "decoded_frames": len(frames),
                "duration_s": round(info.duration, 2),
                "render_s_per_frame": round(info.render_seconds / info.frames, 4),
                "render_s": round(info.render_seconds, 3),
                "total_s": round(info.seconds, 3),
                "bytes": info.bytes,
                "mb": round(info.bytes / 1e6, 3),
            },
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
