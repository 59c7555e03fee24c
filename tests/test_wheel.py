"""The wheel holds the whole package: built from the checkout (the top-level world/, agents/ and
prompts/ folders reached through the package's links), installed in a fresh virtual environment,
every module imports from the installed copy and every data file the code reads is there.

The venv reaches the dependencies through a `.pth` file listing the site-packages of the
interpreter running the tests (no test downloads), while the package itself must come from the
wheel: each module's file is checked to lie in the venv. Not `system_site_packages`: that reaches
the base interpreter's site-packages, which hold nothing when the tests run in a virtual
environment, as the README's install line is usually typed."""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest
from test_layers import ROOT, TOP, sources

pytestmark = pytest.mark.slow

PROBE = r"""
import importlib, json, pkgutil, sys
import mhrc
found, outside = [], []
for info in pkgutil.walk_packages(mhrc.__path__, "mhrc."):
    if info.name.endswith(".__main__"):  # runs the command line; its file is checked below
        continue
    module = importlib.import_module(info.name)
    found.append(info.name)
    if not (module.__file__ or "").startswith(sys.prefix):
        outside.append((info.name, module.__file__))
from importlib import resources
data = {
    "prompts": sorted(p.name for p in resources.files("mhrc.prompts").iterdir() if p.name.endswith(".txt")),
    "scenes": sorted(p.name for p in resources.files("mhrc.world").joinpath("scenes").iterdir()),
    "viewer": sorted(p.name for p in resources.files("mhrc.viewer").iterdir() if p.suffix in (".css", ".js")),
}
print(json.dumps({"found": found, "outside": outside, "data": data, "mhrc": mhrc.__file__}))
"""


def test_the_wheel_installs_in_a_fresh_venv_and_every_module_imports_from_it(tmp_path: Path) -> None:
    # built from a copy, as a clean clone would be (links kept as links): setuptools' build/ folder
    # stays out of the checkout, and nothing stale in it can reach the wheel
    src = tmp_path / "src"
    for name in ("mhrc", *TOP):
        shutil.copytree(ROOT / name, src / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src)
    wheels = tmp_path / "wheels"
    # without PYTHONPATH (bench/bench_suite.py sets it to the tree it times): pip would find the
    # checkout's mhrc on it, call the wheel's requirement satisfied and install nothing
    clean = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(wheels), str(src)],
        capture_output=True,
        text=True,
        timeout=300,
        env=clean,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = wheels.glob("mhrc-*.whl")
    env = tmp_path / "venv"
    venv.create(env, with_pip=False)
    python = env / "bin" / "python"
    (purelib,) = env.glob("lib/python3*/site-packages")
    # plain path lines: appended after the venv's own site-packages (so the wheel's mhrc comes
    # first), and the .pth files in those folders, the editable install's finder among them,
    # are not run
    (purelib / "deps_of_the_test_interpreter.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
        env=clean,
    )
    assert installed.returncode == 0, installed.stderr[-3000:]
    # -I: no checkout on the path (not the working directory, not PYTHONPATH)
    probe = subprocess.run([str(python), "-I", "-c", PROBE], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert probe.returncode == 0, probe.stderr[-3000:]
    got = json.loads(probe.stdout)
    assert got["mhrc"].startswith(str(env)), got["mhrc"]
    assert got["outside"] == [] and len(got["found"]) > 120
    assert set(got["found"]) == sources(ROOT) - {"mhrc", "mhrc.__main__"}
    assert list(env.glob("lib/python3*/site-packages/mhrc/__main__.py"))
    names = {p.name for p in (ROOT / "prompts").glob("*.txt")}
    assert set(got["data"]["prompts"]) == names and names
    assert set(got["data"]["scenes"]) >= {p.name for p in (ROOT / "world" / "scenes").glob("*.json")}
    assert {"page.css", "page.js"} <= set(got["data"]["viewer"])
