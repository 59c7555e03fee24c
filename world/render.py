"""Pictures of a scene with PyBullet's CPU renderer (TinyRenderer), written as PNG."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from .sim import Sim

VIEWS = {
    # name: (camera eye, target, up)
    "top": ((0.0, 0.0, 12.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "perspective": ((-6.5, -6.5, 6.0), (0.0, 0.0, 0.3), (0.0, 0.0, 1.0)),
}


def write_png(path: Path, rgb: np.ndarray) -> None:
    """A minimal 8-bit RGB PNG writer (no imaging library needed)."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def check_drawable(sim: Sim) -> None:
    """ValueError for a world built without its visual meshes (Sim's `visuals`): drawn, its robots
    would show their collision meshes."""
    if not sim.visuals:
        raise ValueError("this world was built without visual meshes: build it with Sim(visuals=True) to render it")


def render(sim: Sim, view: str, width: int = 800, height: int = 600) -> np.ndarray:
    check_drawable(sim)
    eye, target, up = VIEWS[view]
    vm = p.computeViewMatrix(eye, target, up, physicsClientId=sim.cid)
    fov = 45.0 if view == "top" else 55.0
    pm = p.computeProjectionMatrixFOV(fov, width / height, 0.1, 50.0, physicsClientId=sim.cid)
    _, _, px, _, _ = p.getCameraImage(width, height, vm, pm, renderer=p.ER_TINY_RENDERER, physicsClientId=sim.cid)
    return np.reshape(np.asarray(px, dtype=np.uint8), (height, width, 4))[:, :, :3]


def render_scene(
    scene: str, out_dir: Path, *, seed: int = 0, n_objects: int = 6, task: str = "pack_objects"
) -> list[Path]:
    """Top-down and perspective PNGs of `scene` with one generated episode's objects."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    with Sim(task=task, scene=scene, seed=seed, n_objects=n_objects, visuals=True) as sim:
        for view in VIEWS:
            path = out_dir / f"{scene}_{view}.png"
            write_png(path, render(sim, view))
            paths.append(path)
    return paths
