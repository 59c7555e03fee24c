"""A griffe extension for the API pages: `mhrc.agents` and `mhrc.world` live outside `mhrc/`.

setuptools installs `agents/` as `mhrc.agents` and `world/` as `mhrc.world` (`package-dir` in
pyproject.toml). griffe reads source statically and looks for them under `mhrc/`, where they
are not, so `::: mhrc.agents.policy` would not be found. When griffe has loaded the `mhrc`
package, this loads each such directory from the same mapping and hangs it under `mhrc`, so
their objects get their installed paths (`mhrc.agents.policy.Policy`) and aliases into them
(from `mhrc.testing`) resolve. Nothing is imported: no module of mhrc runs during the build.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import griffe

ROOT = Path(__file__).resolve().parents[2]  # docs/hooks/ -> the project root


def outside_packages(root: Path = ROOT, top: str = "mhrc") -> dict[str, Path]:
    """The direct subpackages of `top` whose source directory is not `top/<name>`, from pyproject."""
    mapping: dict[str, str] = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    found = {}
    for name, directory in mapping.items():
        parent, _, child = name.rpartition(".")
        source = root / directory
        if parent == top and source != root / top / child and (source / "__init__.py").is_file():
            found[child] = source
    return found


class InstalledLayout(griffe.Extension):
    """Attach `mhrc.agents` and `mhrc.world` (from their own directories) to the loaded `mhrc`."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        if pkg.name != "mhrc":
            return
        for child, source in outside_packages().items():
            if child in pkg.members:
                continue
            module = loader.load(str(source))  # loaded under its directory's name, e.g. "agents"
            assert isinstance(module, griffe.Module)
            if loader.modules_collection.members.get(module.name) is module:
                del loader.modules_collection.members[module.name]  # it is not a top-level package
            pkg.set_member(child, module)
