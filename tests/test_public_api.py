"""The public surface: the wire (a golden `mhrc schema`, so a change of any payload is a visible
diff) and the names a user imports (pinned, so one cannot disappear by accident)."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from mhrc.core import schema

GOLDEN = Path(__file__).parent / "golden" / "schema.json"


def test_the_wire_is_the_golden_schema() -> None:
    """Regenerate with `mhrc schema > tests/golden/schema.json` when a payload changes on purpose
    (and bump PROTOCOL_VERSION if an old participant could no longer read it)."""
    assert schema.document() == json.loads(GOLDEN.read_text(encoding="utf-8")), (
        "the bus payloads differ from tests/golden/schema.json: if on purpose, regenerate it with `mhrc schema`"
    )


PUBLIC = Path(__file__).parent / "golden" / "public_api.json"  # module -> its __all__, as documented (docs/reference/)


def surface() -> dict[str, list[str]]:
    return {m: sorted(importlib.import_module(m).__all__) for m in json.loads(PUBLIC.read_text(encoding="utf-8"))}


def test_the_public_surface_is_pinned() -> None:
    """A name added to or dropped from a public module's __all__ is a visible diff: update
    tests/golden/public_api.json on purpose (and the docs' reference pages say why)."""
    assert surface() == json.loads(PUBLIC.read_text(encoding="utf-8"))


@pytest.mark.parametrize("module", sorted(json.loads(PUBLIC.read_text(encoding="utf-8"))))
def test_every_public_name_imports(module: str) -> None:
    mod = importlib.import_module(module)
    missing = [name for name in mod.__all__ if not hasattr(mod, name)]
    assert not missing, f"{module}.__all__ names what it does not have: {missing}"
