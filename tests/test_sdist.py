"""The layout's loose ends: the top-level world/ and agents/ folders import only as mhrc.world and
mhrc.agents (under a bare name, one clear line says so), and the sdist (where the package's links
to them become copies) installs in a fresh venv and runs an episode.

The venv sees this environment's dependencies through a .pth file listing this interpreter's
site-packages (not system_site_packages, which would reach the base interpreter's instead): no
test downloads, and the package itself must come from the sdist."""

from __future__ import annotations

import json
import shutil
import site
import subprocess
import sys
import tarfile
import venv
from pathlib import Path

import pytest
from test_layers import ROOT, TOP


@pytest.mark.parametrize(("bare", "real"), [("world.roster", "mhrc.world"), ("agents.parse", "mhrc.agents")])
def test_a_top_level_folder_under_a_bare_name_fails_with_one_line_naming_mhrc(bare: str, real: str) -> None:
    """From the repository's root, `import world.roster` would load the files a second time, as
    modules other than mhrc.world's (`world.roster.Roster is not mhrc.world.roster.Roster`)."""
    out = subprocess.run(
        [sys.executable, "-c", f"import {bare}"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode != 0
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: ") and f"as {real}, not as {bare.split('.')[0]!r}" in last, out.stderr


EPISODE = r"""
import asyncio, json, sys
import mhrc, mhrc.world.roster
from mhrc.testing import run_episode

result = asyncio.run(run_episode(seed=0, horizon=3, n_objects=3, trace=sys.argv[1], timeout=240))
print(json.dumps({"mhrc": mhrc.__file__, "world": mhrc.world.roster.__file__, "reason": result.done.reason,
                  "ticks": result.metrics.temporal_steps, "lines": len(result.records)}))
"""


@pytest.mark.slow
def test_the_sdist_installs_in_a_fresh_venv_and_runs_an_episode(tmp_path: Path) -> None:
    src = tmp_path / "src"  # a copy, as a clean clone would be (links kept as links)
    for name in ("mhrc", *TOP):
        shutil.copytree(ROOT / name, src / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src)
    dist = tmp_path / "dist"
    built = subprocess.run(
        [sys.executable, "-c", f"from setuptools import build_meta; print(build_meta.build_sdist({str(dist)!r}))"],
        cwd=src,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    sdist = dist / built.stdout.strip().splitlines()[-1]
    with tarfile.open(sdist) as tar:
        members = {m.name.split("/", 1)[1]: m for m in tar.getmembers() if "/" in m.name}
    assert "mhrc/world/roster.py" in members and members["mhrc/world/roster.py"].isfile()  # the link, copied
    assert members["mhrc/prompts/tabletop_arm_system.txt"].isfile()

    env = tmp_path / "venv"
    venv.create(env, with_pip=False)
    python = env / "bin" / "python"
    (purelib,) = env.glob("lib/python3*/site-packages")
    (purelib / "_outer_dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n", encoding="utf-8")
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-build-isolation",
         "--no-index", "-q", str(sdist)],
        capture_output=True,
        text=True,
        timeout=600,
    )  # fmt: skip
    assert installed.returncode == 0, installed.stderr[-3000:]
    # -I: no checkout on the path (not the working directory, not PYTHONPATH)
    run = subprocess.run(
        [str(python), "-I", "-c", EPISODE, str(tmp_path / "trace.jsonl")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["mhrc"].startswith(str(env)) and got["world"].startswith(str(purelib)), got
    assert got["reason"] in ("horizon", "success") and got["ticks"] >= 1 and got["lines"] > 10, got
