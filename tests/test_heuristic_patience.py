"""A teammate that never does what was asked does not strand the heuristic team: the lead fetcher
takes back the surfaces she handed to a scout that reports nothing for a few steps (agents/
heuristic_fetcher.py, PATIENCE_TICKS), as a person or a model playing David may never report.
With four objects one target lies on a surface of the house (world/tasks.py, scatter), which
only the scout was asked to look at."""

from __future__ import annotations

import asyncio

import pytest

from mhrc.agents import heuristic_fetcher
from mhrc.core.protocol import Communicate, Navigate
from mhrc.testing import ScriptedPolicy, run_episode

pytestmark = pytest.mark.slow  # two whole episodes

EPISODE = {"seed": 0, "n_objects": 4, "horizon": 40, "schedule": "lockstep"}


def _idle_david() -> object:
    return asyncio.run(run_episode({"david": ScriptedPolicy([], name="idle")}, **EPISODE))


@pytest.fixture(scope="module")
def idle_david():  # type: ignore[no-untyped-def]
    """Alice and Bob heuristic, David a robot that only waits."""
    return _idle_david()


def test_a_david_who_only_waits_does_not_strand_the_team(idle_david) -> None:  # type: ignore[no-untyped-def]
    m = idle_david.metrics
    assert idle_david.done.reason == "success", (idle_david.done.reason, m.placed, m.total)
    assert m.action_steps_per_robot["david"] == 0


def test_alice_takes_back_the_surfaces_after_the_patience(idle_david) -> None:  # type: ignore[no-untyped-def]
    alice = idle_david.results("alice")
    handed = [r for r in alice if isinstance(r.action, Communicate) and r.action.to == "david"]
    assert handed, "Alice never handed David any surface: the test does not test the patience"
    surfaces = {s.strip(" .") for s in handed[0].action.content.split(":", 1)[1].split(",")}
    looked = [r.tick for r in alice if isinstance(r.action, Navigate) and r.action.target in surfaces]
    assert looked and min(looked) > handed[0].tick + heuristic_fetcher.PATIENCE_TICKS, (surfaces, looked)


def test_without_the_patience_the_same_episode_is_stranded(monkeypatch: pytest.MonkeyPatch) -> None:
    """The same episode with a patience that never ends: Alice awaits David's reports forever."""
    monkeypatch.setattr(heuristic_fetcher, "PATIENCE_TICKS", 10**6)
    result = _idle_david()
    assert result.done.reason == "horizon"  # type: ignore[attr-defined]
