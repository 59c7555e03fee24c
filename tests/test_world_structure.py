"""The shape of the world package: no import circle inside it, one registered skill per action
type, no module over 500 lines."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import get_args

import mhrc.world
from mhrc.core.protocol import Action, Communicate

ROOT = Path(mhrc.world.__path__[0])


def _modules() -> dict[str, Path]:
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = ["mhrc", "world", *path.relative_to(ROOT).with_suffix("").parts]
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The world modules `name` imports anywhere in its source (TYPE_CHECKING and function
    bodies included); `from pkg import sub` counts as importing the submodule, not the package."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name in modules)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.add(sub if sub in modules else base)
    return {m for m in out if m in modules and m != name}


def test_no_world_module_imports_one_that_imports_it_back() -> None:
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}

    def reaches(start: str) -> set[str]:
        seen: set[str] = set()
        todo = list(graph[start])
        while todo:
            m = todo.pop()
            if m not in seen:
                seen.add(m)
                todo.extend(graph[m])
        return seen

    circles = sorted(m for m in graph if m in reaches(m))
    assert not circles, f"modules on an import circle: {', '.join(circles)}"


def test_every_action_but_communicate_runs_as_one_registered_skill() -> None:
    from mhrc.world.skills import SKILLS

    actions = set(get_args(get_args(Action)[0]))  # Annotated[Union[...], discriminator]
    assert Communicate in actions and len(actions) > 2
    assert set(SKILLS) == actions - {Communicate}  # communicate is the world service's


def test_no_world_module_is_over_500_lines() -> None:
    sizes = {name: len(path.read_text(encoding="utf-8").splitlines()) for name, path in _modules().items()}
    assert {n: s for n, s in sizes.items() if s > 500} == {}
