"""The house's layers hold (docs/architecture.md): import-linter's contracts in pyproject.toml
(the layers, the world's and the agents' independence, and no circles between the modules of any
package), over every module of the package, the top-level world/, agents/ and prompts/ folders
included; and a wrong import planted in a copy of the tree is caught by the same command."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
# The design card's top-level folders: the package mhrc/ reaches each through a link of its own
# name (mhrc/world -> ../world), so the import names stay mhrc.world, mhrc.agents, mhrc.prompts.
TOP = ("world", "agents", "prompts")


def lint_imports(cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    # this interpreter's own first: a lint-imports earlier on PATH may belong to another Python
    own = Path(sys.executable).parent / "lint-imports"
    exe = str(own) if own.exists() else shutil.which("lint-imports") or str(own)
    # --no-cache: the copy below must be read afresh, never from the checkout's cache.
    return subprocess.run(
        [exe, "--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=300, env={**os.environ, **env}
    )


def sources(root: Path) -> set[str]:
    """The module names of every .py file of the package, read from the folders themselves."""
    names = set()
    for top in (root / "mhrc", *(root / t for t in TOP)):
        for p in top.rglob("*.py"):
            if "__pycache__" in p.parts:
                continue
            rel = p.relative_to(root).with_suffix("")
            parts = rel.parts if rel.parts[0] == "mhrc" else ("mhrc", *rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            names.add(".".join(parts))
    return names


def test_the_top_level_folders_are_real_and_the_package_links_to_them() -> None:
    for name in TOP:
        assert (ROOT / name).is_dir() and not (ROOT / name).is_symlink(), name
        link = ROOT / "mhrc" / name
        assert link.is_symlink() and os.readlink(link) == f"../{name}", name


def test_the_import_contracts_hold() -> None:
    done = lint_imports(ROOT)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "3 kept, 0 broken" in done.stdout


def test_the_import_graph_holds_every_module_of_every_folder() -> None:
    """The contracts are not kept vacuously: import-linter's graph (grimp's) has every module the
    folders hold, the ones behind the links too."""
    graph = grimp.build_graph("mhrc", include_external_packages=False, cache_dir=None)
    want = sources(ROOT)
    assert want - graph.modules == set()
    assert len([m for m in want if m.startswith(("mhrc.world.", "mhrc.agents."))]) > 40


PLANTS = {
    # the world reaching up into the assembly: a layer broken
    "world/_planted_up.py": "import mhrc.run.serve\n",
    # the agents reaching sideways into the world: independence broken
    "agents/_planted_side.py": "import mhrc.world.sim\n",
    # two modules of the core importing each other: a circle
    "mhrc/core/_planted_a.py": "import mhrc.core._planted_b\n",
    "mhrc/core/_planted_b.py": "import mhrc.core._planted_a\n",
}


def test_a_wrong_import_planted_anywhere_is_caught(tmp_path: Path) -> None:
    """A copy of the tree (links kept as links) with one wrong import of each kind, the first two
    in the top-level folders: every contract breaks, naming the planted module."""
    for name in ("mhrc", *TOP):
        shutil.copytree(ROOT / name, tmp_path / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    clean = lint_imports(tmp_path, PYTHONPATH=str(tmp_path))
    assert clean.returncode == 0, clean.stdout[-3000:]
    for path, text in PLANTS.items():
        (tmp_path / path).write_text(text, encoding="utf-8")
    done = lint_imports(tmp_path, PYTHONPATH=str(tmp_path))
    assert done.returncode != 0
    assert "0 kept, 3 broken" in done.stdout, done.stdout[-4000:]
    for planted in ("mhrc.world._planted_up -> mhrc.run.serve", "mhrc.agents._planted_side -> mhrc.world.sim"):
        assert planted in done.stdout, planted
    assert "._planted_b -> ._planted_a" in done.stdout


def test_no_source_module_is_over_500_lines() -> None:
    files = {p.resolve() for d in ("mhrc", *TOP, "bench") for p in (ROOT / d).rglob("*.py")}
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text(encoding="utf-8").splitlines())) > 500}
    assert not long, f"modules over 500 lines (split them by job): {long}"
