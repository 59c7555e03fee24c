"""Golden tests of the rendered prompts, for each role at step 1 and at a later step.

Regenerate after a deliberate prompt change with `MHRC_UPDATE_GOLDEN=1 pytest tests/test_prompts.py`
and review the diff of tests/golden/.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mhrc.agents.llm import ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy
from mhrc.protocol import ActionResult, Navigate, RobotMessage, Wait
from mhrc.world.sim import Sim

GOLDEN = Path(__file__).parent / "golden"


def _check(name: str, text: str) -> None:
    path = GOLDEN / name
    if os.environ.get("MHRC_UPDATE_GOLDEN"):
        path.write_text(text, encoding="utf-8")
    assert path.exists(), f"{path} missing: run with MHRC_UPDATE_GOLDEN=1"
    assert text == path.read_text(encoding="utf-8")


def _prompt(policy: LLMPolicy, obs) -> str:  # type: ignore[no-untyped-def]
    return "\n\n=====\n\n".join(m["content"] for m in policy.render(obs))


@pytest.mark.parametrize("robot", ["alice", "bob", "david"])
def test_prompts_at_step_1_and_later(robot: str) -> None:
    with Sim(seed=0, n_objects=4) as sim:
        policy = LLMPolicy(robot, ScriptedClient([]))
        _check(f"{robot}_step1.txt", _prompt(policy, sim.observe(robot, 0)))

        # three steps later: two actions with feedback, one message received
        for tick in range(3):
            action = Navigate(target="table_1", stand_pose=tick) if "navigate" in sim.capabilities(robot) else Wait()
            outcome = sim.execute(robot, action)
            obs = sim.observe(robot, tick + 1)
            policy.record(ActionResult(goal_id=f"g{tick}", robot=robot, tick=tick, action=action, outcome=outcome, observation=obs))
        other = "bob" if robot != "bob" else "alice"
        policy.memory.messages.append(f"from {other} at step 2: Please report what you find.")
        obs = obs.model_copy(update={"new_messages": [RobotMessage(sender=other, to=robot, content="Anything new?", tick=3)]})
        policy.memory.messages += [f"from {m.sender} at step {m.tick}: {m.content}" for m in obs.new_messages]
        text = _prompt(policy, obs)
        assert text.count("(latest)") == 3
        _check(f"{robot}_step4.txt", text)


def test_the_cap_keeps_the_latest_entries_whole() -> None:
    with Sim(seed=0) as sim:
        obs = sim.observe("alice", 50)
        capped, uncapped = LLMPolicy("alice", ScriptedClient([])), LLMPolicy("alice", ScriptedClient([]), prompt_cap_chars=None)
        for policy in (capped, uncapped):
            for i in range(50):
                policy.memory.feedback.append(f"step {i}: navigate(table_1, 0) -> You reached stand pose 0 of table_1. There is nothing on table_1.")
                policy.memory.actions.append(f"step {i}: navigate(table_1, 0)")
        small, big = _prompt(capped, obs), _prompt(uncapped, obs)
        assert len(small) < len(big) - 2500
        assert "older entries omitted" in small and "step 49: navigate(table_1, 0) -> You reached" in small
        assert "step 0: navigate(table_1, 0) -> You" in big and "step 0: navigate(table_1, 0) -> You" not in small


def test_ablations_change_the_prompt() -> None:
    with Sim(seed=0) as sim:
        obs = sim.observe("alice", 3)
        for kw, gone in (({"feedback": False}, "step 2: wait() -> done"), ({"history": False}, "step 1: wait()\n")):
            policy = LLMPolicy("alice", ScriptedClient([]), **kw)  # type: ignore[arg-type]
            policy.memory.feedback += ["step 1: wait() -> done", "step 2: wait() -> done"]
            policy.memory.actions += ["step 1: wait()", "step 2: wait()"]
            assert gone not in _prompt(policy, obs)
        absent = LLMPolicy("alice", ScriptedClient([]), teammates_absent=("david",))
        text = _prompt(absent, obs)
        assert "David is not part of the team" in text and "- david:" not in text
