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


PUBLIC = {
    "mhrc.testing": {
        "ScriptedPolicy", "ScriptedModelServer", "ModelReply", "ModelCall", "LoopbackWorld", "world_on_loopback",
        "run_episode", "EpisodeResult",
    },
    "mhrc.agents.policy": {"Policy", "Decision"},
}  # fmt: skip


@pytest.mark.parametrize("module", sorted(PUBLIC))
def test_the_documented_names_stay_importable(module: str) -> None:
    mod = importlib.import_module(module)
    missing = {name for name in PUBLIC[module] if not hasattr(mod, name)}
    assert not missing, f"{module} lost public names: {sorted(missing)}"
    exported = set(getattr(mod, "__all__", ()))
    assert PUBLIC[module] <= exported, f"{module}.__all__ lacks {sorted(PUBLIC[module] - exported)}"
