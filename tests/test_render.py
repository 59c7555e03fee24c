from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path


def test_render_writes_two_views_as_png(tmp_path: Path) -> None:
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "render",
        "--scene",
        "bathroom",
        "--task",
        "sort_solids",
        "--out",
        str(tmp_path),
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for view in ("top", "perspective"):
        data = (tmp_path / f"bathroom_{view}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        assert struct.unpack(">II", data[16:24]) == (800, 600)
        assert len(data) > 10_000  # a picture: a blank frame compresses to a few kB


def test_scenes_lists_the_layouts() -> None:
    out = subprocess.run([sys.executable, "-m", "mhrc", "scenes"], capture_output=True, text=True, timeout=60)
    assert (
        out.returncode == 0
        and all(f"{name}:" in out.stdout for name in ("kitchen", "bathroom", "bedroom"))
        and "drawer_unit" in out.stdout
    )
    bad = subprocess.run(
        [sys.executable, "-m", "mhrc", "render", "--scene", "castle"], capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 2 and "unknown scene 'castle'" in bad.stderr
